"""Detection over a whole session: every scan frame of every camera, in parallel, resumable.

Frames are independent, so they are split into chunks and handed to a
:class:`concurrent.futures.ProcessPoolExecutor` (workers read their own images: only file names
and result tables cross process boundaries). ``traces.parquet`` is rewritten atomically every
``checkpoint_s`` seconds and at the end, with the list of processed ``(camera, frame)`` pairs in
its metadata; ``resume=True`` skips those, including frames that had no candidate.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from scanrig.errors import FileFormatError, InputError
from scanrig.io.object_poses import object_poses_path
from scanrig.io.session import Session, describe_image, natural_key, read_image
from scanrig.laser.median_dark import median_dark
from scanrig.laser.stripes import DIRECTIONS
from scanrig.laser.image import LASER_COLORS
from scanrig.laser.traces import empty_table, read_traces, write_traces

MODES = ("spot", "stripe")
#: Where a camera's laser-off frame comes from: its ``scan/<camera>/dark.<ext>`` only ("file"), or,
#: where it has none, the median of its scan frames ("median", :mod:`scanrig.laser.median_dark`).
DARK_SOURCES = ("file", "median")
#: Options added after ``traces.parquet`` files were first written: such files used their defaults.
_LATER_OPTIONS = ("direction", "dark")
#: Frames per task sent to a worker: large enough to hide the pickling, small enough to balance.
_CHUNK_FRAMES = 8


@dataclass(frozen=True)
class DetectOptions:
    """What to detect and how (recorded in ``traces.parquet``; resuming requires the same).

    Attributes
    ----------
    mode : {"spot", "stripe"}
    color : {"grey", "red", "green", "blue"}
    roi : (u0, v0, u1, v1) or None
        Region of interest applied to every camera, pixels.
    k_detect : float
        Detection threshold in noise σ of the 3 × 3 box sum.
    direction : {"auto", "rows", "columns"}
        Stripe mode: the lines a stripe is scanned along ("auto": chosen per block). A fixed
        laser plane seen steeply (most single-camera scanners) is best scanned along rows only, so
        that no texture edge is taken along columns where the laser is not.
    dark : {"file", "median"}
        "median": a camera without ``scan/<camera>/dark.<ext>`` takes the per-pixel median of its
        scan frames as its laser-off frame (a laser swept over a fixed scene, not a moving object).
    """

    mode: str = "spot"
    color: str = "grey"
    roi: tuple[int, int, int, int] | None = None
    k_detect: float = 6.0
    direction: str = "auto"
    dark: str = "file"

    def __post_init__(self):
        if self.mode not in MODES:
            raise InputError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.color not in LASER_COLORS:
            raise InputError(f"color must be one of {LASER_COLORS}, got {self.color!r}")
        if not self.k_detect > 0:
            raise InputError(f"k_detect must be a positive number of noise sigma, got {self.k_detect!r}")
        if self.direction not in DIRECTIONS:
            raise InputError(f"direction must be one of {DIRECTIONS}, got {self.direction!r}")
        if self.mode == "spot" and self.direction != "auto":
            raise InputError(f"direction {self.direction!r} applies to stripes; spot mode takes no direction")
        if self.dark not in DARK_SOURCES:
            raise InputError(f"dark must be one of {DARK_SOURCES}, got {self.dark!r}")

    def as_dict(self) -> dict:
        return {"mode": self.mode, "color": self.color, "roi": None if self.roi is None else list(self.roi),
                "k_detect": self.k_detect, "direction": self.direction, "dark": self.dark}


def options_from_session(session: Session, mode: str | None = None, color: str | None = None,
                         roi=None, k_detect: float = 6.0, direction: str = "auto", dark: str = "file") -> DetectOptions:
    """Options with ``mode`` and ``color`` defaulting to ``laser_mode`` / ``laser_color`` of session.toml."""
    settings = session.settings()
    return DetectOptions(mode or settings.get("laser_mode", "spot"), color or settings.get("laser_color", "grey"),
                         None if roi is None else tuple(int(x) for x in roi), k_detect, direction, dark)


@dataclass
class _Job:
    camera: str
    frames: list[tuple[str, str]]  # (stem, path)
    dark_path: str | None
    dark_image: np.ndarray | None  # the median of the camera's frames (options.dark == "median")
    shape: tuple[int, ...]
    dtype: str
    reference: str  # the file that fixed shape and dtype
    options: DetectOptions


def detect_session(
    root: str | Path,
    options: DetectOptions | None = None,
    workers: int = 1,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
    checkpoint_s: float = 30.0,
) -> pa.Table:
    """Detect laser traces in every scan frame of a session and write ``traces.parquet``.

    Parameters
    ----------
    root : path
        Session folder (DESIGN.md §4): images in ``scan/<camera>/<frame>.<ext>``, optional
        ``scan/<camera>/dark.<ext>``.
    options : DetectOptions, optional
        Default: :func:`options_from_session`.
    workers : int
        Processes; 1 runs in this process.
    resume : bool
        Keep an existing ``traces.parquet`` made with the same options and skip its frames.
    progress : callable, optional
        ``progress(done, total)`` after each chunk of frames.
    checkpoint_s : float
        Seconds between intermediate writes of ``traces.parquet``.

    Returns
    -------
    pyarrow.Table
        All rows written, ordered by camera (session order), frame (natural order), line, rank.

    Raises
    ------
    FileFormatError
        Naming the file: unreadable image, wrong bit depth, a frame whose size or bit depth differs
        from the camera's other frames or its dark frame, a traces file made with other options.
    InputError
        ``options.dark == "median"`` where the object moves (``scan/object_poses.csv``) or a camera
        without a dark frame has fewer than :data:`~scanrig.laser.median_dark.MIN_FRAMES` frames.
    """
    session = Session(root)
    options = options or options_from_session(session)
    if workers < 1:
        raise InputError(f"workers must be at least 1, got {workers}")
    cameras = session.camera_names("scan")
    tables, done = [empty_table()], set()
    if resume and session.traces_path.exists():
        table, meta = read_traces(session.traces_path)
        made_with = meta.get("options")
        if isinstance(made_with, dict):
            defaults = DetectOptions().as_dict()
            made_with = made_with | {k: defaults[k] for k in _LATER_OPTIONS if k not in made_with}
        if made_with != options.as_dict():
            raise FileFormatError(session.traces_path, f"was made with options {made_with}, "
                                  f"not {options.as_dict()}; run without --resume to start again")
        tables.append(table)
        done = {tuple(x) for x in meta.get("frames_done", [])}
    if options.dark == "median" and object_poses_path(session.root).exists():
        raise InputError(f"{object_poses_path(session.root)}: the object moves between frames, so the median of "
                         "its frames is not a laser-off frame; take one (scan/<camera>/dark.<ext>) instead")
    jobs = _jobs(session, cameras, options, done)
    total = sum(len(j.frames) for j in jobs)
    finished = sorted(done)
    last_write = time.monotonic()

    def collect(job: _Job, result):
        nonlocal last_write
        if isinstance(result, tuple):  # (path, reason) of a bad input file
            raise FileFormatError(*result)
        tables.append(result)
        finished.extend((job.camera, stem) for stem, _ in job.frames)
        if progress:
            progress(len(finished) - len(done), total)
        if time.monotonic() - last_write > checkpoint_s:
            _write(session, cameras, tables, finished, options)
            last_write = time.monotonic()

    if workers == 1 or len(jobs) <= 1:
        for job in jobs:
            collect(job, _run_job(job))
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(_run_job, job): job for job in jobs}
            try:
                for fut in as_completed(futures):
                    collect(futures[fut], fut.result())
            except BaseException:
                for fut in futures:
                    fut.cancel()
                raise
    return _write(session, cameras, tables, finished, options)


def _jobs(session: Session, cameras: list[str], options: DetectOptions, done: set) -> list[_Job]:
    """Chunks of frames still to do, with each camera's reference shape and dark frame."""
    jobs = []
    for cam in cameras:
        paths = session.image_paths("scan", cam)
        dark = session.dark_path(cam)
        todo = [(stem, str(p)) for stem, p in paths.items() if (cam, stem) not in done]
        if not todo:
            continue
        reference = dark or paths[next(iter(paths))]
        img = read_image(reference)
        median = median_dark(list(paths.values()), cam) if dark is None and options.dark == "median" else None
        for k in range(0, len(todo), _CHUNK_FRAMES):
            jobs.append(_Job(cam, todo[k : k + _CHUNK_FRAMES], None if dark is None else str(dark), median,
                             img.shape, str(img.dtype), str(reference), options))
    return jobs


def _run_job(job: _Job):
    """Detect in a chunk of frames (runs in a worker). Returns a table, or (path, reason) on bad input."""
    from scanrig.laser.spots import detect_spots
    from scanrig.laser.stripes import detect_stripe

    options = job.options
    detect, scan = (detect_spots, {}) if options.mode == "spot" else (detect_stripe, {"direction": options.direction})
    path = job.dark_path
    try:
        dark = job.dark_image if job.dark_path is None else read_image(job.dark_path)
        out = []
        for stem, path in job.frames:
            img = read_image(path)
            if img.shape != job.shape or str(img.dtype) != job.dtype:
                return (path, f"frame is {describe_image(img.shape, img.dtype)} but {Path(job.reference).name} of "
                              f"camera {job.camera!r} is {describe_image(job.shape, job.dtype)}")
            out.append(detect(img, color=options.color, dark=dark, roi=options.roi,
                              k_detect=options.k_detect, camera=job.camera, frame=stem, **scan))
    except FileFormatError as exc:
        return (str(exc.path), exc.reason)
    except InputError as exc:
        return (path, str(exc))
    return pa.concat_tables(out) if out else empty_table()


def _write(session: Session, cameras: list[str], tables: list[pa.Table], finished, options) -> pa.Table:
    """Concatenate, order canonically and write ``traces.parquet`` atomically."""
    table = pa.concat_tables(tables)
    if len(table):
        cam_rank = {c: i for i, c in enumerate(cameras)}
        frames = table.column("frame").to_pylist()
        stems = sorted(set(frames), key=natural_key)
        frame_rank = {s: i for i, s in enumerate(stems)}
        order = np.lexsort((table.column("rank").to_numpy(), table.column("line").to_numpy(),
                            np.array([frame_rank[f] for f in frames]),
                            np.array([cam_rank.get(c, len(cam_rank)) for c in table.column("camera").to_pylist()])))
        table = table.take(order)
    from scanrig import __version__

    meta = {"format_version": 1, "created_by": f"scanrig {__version__}", "options": options.as_dict(),
            "frames_done": [list(x) for x in sorted(set(map(tuple, finished)))]}
    write_traces(session.traces_path, table, meta)
    return table
