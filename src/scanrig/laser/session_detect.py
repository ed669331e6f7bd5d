"""Detection over a whole session: every scan frame of every camera, in parallel, resumable.

Frames are independent, so they are split into chunks and handed to a
:class:`concurrent.futures.ProcessPoolExecutor` (workers read their own images: only file names
and result tables cross process boundaries). ``traces.parquet`` is rewritten atomically every
``checkpoint_s`` seconds and at the end (once some frame has a candidate), with the list of processed ``(camera, frame)`` pairs in
its metadata; ``resume=True`` skips those, including frames that had no candidate.

Frames are taken as they are, not as ``laser_color`` says: a colour frame whose channels are
equal is detected as grey, each channel is clipped where its data clip (found from the frames
unless ``saturation_level`` says), and :func:`colour_mismatches` names the cameras whose frames
show a laser of another colour. A frame
whose scene itself reaches the clip level (:class:`~scanrig.laser.bright_scene.BrightSceneWarning`) is
named in that warning, issued again in the calling process whichever worker detected it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from scanrig.errors import FileFormatError, InputError
from scanrig.io.object_poses import object_poses_path
from scanrig.io.session import Session, describe_image, natural_key, read_image
from scanrig.laser.bright_scene import BrightSceneWarning
from scanrig.laser.channels import LASER_COLORS
from scanrig.laser.colour_check import (CHANNEL_COLOURS, LaserColourError, colour_advice, colour_shown, grey_frames,
                                        one_colour)
from scanrig.laser.exposure import exposure_gains, mismatched, row_gains
from scanrig.laser.median_dark import median_dark
from scanrig.laser.stripes import DIRECTIONS
from scanrig.laser.traces import empty_table, read_traces, write_traces

MODES = ("spot", "stripe")
#: Where a frame's laser-off frame comes from: its own ``scan/<camera>/dark/<frame>.<ext>`` or its
#: camera's ``scan/<camera>/dark.<ext>`` only ("file"), or, where it has neither, the median of its
#: camera's scan frames ("median", :mod:`scanrig.laser.median_dark`).
DARK_SOURCES = ("file", "median")
#: Options added after ``traces.parquet`` files were first written, and the values such files were
#: made with: before ``saturation_level`` every frame was clipped at its dtype's maximum (None).
_LATER_OPTIONS = {"direction": "auto", "dark": "file", "saturation_level": None}
#: A camera's frame shows a laser of another colour (:func:`colour_mismatches`) only where that
#: colour has a rank-0 stripe candidate on at least this many scan lines (spots: one candidate).
_LEAST_STRIPE_LINES = 20
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
        Every frame takes its own laser-off frame ``scan/<camera>/dark/<frame>.<ext>`` if it has
        one, else its camera's ``scan/<camera>/dark.<ext>``. "median": a frame with neither takes
        the per-pixel median of its camera's scan frames (a laser swept over a fixed scene, not a
        moving object).
    saturation_level : float or "auto"
        DN at which pixels clip, or "auto": each channel's level found from the frames
        (:func:`~scanrig.laser.clip_level.channel_clip_levels`): a 16-bit file often holds a 10-, 12-
        or 14-bit camera's data, which clip below 65535, and a colour camera's white balance scales
        a channel after the sensor clips, so a channel with a gain below 1 clips below 255.
    """

    mode: str = "spot"
    color: str = "grey"
    roi: tuple[int, int, int, int] | None = None
    k_detect: float = 6.0
    direction: str = "auto"
    dark: str = "file"
    saturation_level: float | str = "auto"

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
        level = self.saturation_level
        if not (level == "auto" or (isinstance(level, (int, float)) and not isinstance(level, bool)
                                    and math.isfinite(level) and level > 0)):
            raise InputError(f"saturation_level must be a positive number of DN or 'auto', got {level!r}")

    def as_dict(self) -> dict:
        return {"mode": self.mode, "color": self.color, "roi": None if self.roi is None else list(self.roi),
                "k_detect": self.k_detect, "direction": self.direction, "dark": self.dark,
                "saturation_level": self.saturation_level}


def options_from_session(session: Session, mode: str | None = None, color: str | None = None,
                         roi=None, k_detect: float = 6.0, direction: str = "auto", dark: str = "file",
                         saturation_level: float | str | None = None) -> DetectOptions:
    """Options with ``mode``, ``color`` and ``saturation_level`` defaulting to ``laser_mode``,
    ``laser_color`` and ``saturation_level`` of session.toml."""
    settings = session.settings()
    return DetectOptions(mode or settings.get("laser_mode", "spot"), color or settings.get("laser_color", "grey"),
                         None if roi is None else tuple(int(x) for x in roi), k_detect, direction, dark,
                         settings.get("saturation_level", "auto") if saturation_level is None else saturation_level)


@dataclass
class _Job:
    camera: str
    frames: list[tuple[str, str, str | None]]  # (stem, path, its laser-off frame's path)
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
        ``scan/<camera>/dark.<ext>`` and ``scan/<camera>/dark/<frame>.<ext>`` (a frame's own
        laser-off frame, used instead of the camera's).
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
        When no frame has a candidate it is empty and nothing is written.

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
            made_with = made_with | {k: v for k, v in _LATER_OPTIONS.items() if k not in made_with}
        if made_with != options.as_dict():
            raise FileFormatError(session.traces_path, f"was made with options {made_with}, "
                                  f"not {options.as_dict()}; run without --resume to start again")
        tables.append(table)
        done = {tuple(x) for x in meta.get("frames_done", [])}
    if options.dark == "median" and object_poses_path(session.root).exists():
        raise InputError(f"{object_poses_path(session.root)}: the object moves between frames, so the median of "
                         "its frames is not a laser-off frame; take one at every step "
                         "(scan/<camera>/dark/<frame>.<ext>) instead")
    jobs = _jobs(session, cameras, options, done)
    total = sum(len(j.frames) for j in jobs)
    finished = sorted(done)
    last_write = time.monotonic()

    def collect(job: _Job, result):
        nonlocal last_write
        if isinstance(result, tuple):  # (path, reason) of a bad input file
            raise FileFormatError(*result)
        for message in result.warnings:
            warnings.warn(BrightSceneWarning(message), stacklevel=3)
        tables.append(result.table)
        finished.extend((job.camera, stem) for stem, _, _ in job.frames)
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
    """Chunks of frames still to do, each frame with its laser-off frame (its own, else the
    camera's), and each camera's reference shape and median laser-off frame."""
    jobs = []
    for cam in cameras:
        paths = session.image_paths("scan", cam)
        dark = session.dark_path(cam)
        own = session.frame_dark_paths(cam)
        dark_of = {stem: str(path) for stem in paths if (path := own.get(stem, dark)) is not None}
        todo = [(stem, str(p), dark_of.get(stem)) for stem, p in paths.items() if (cam, stem) not in done]
        if not todo:
            continue
        reference = dark or paths[next(iter(paths))]
        img = read_image(reference)
        median = (median_dark(list(paths.values()), cam)
                  if dark is None and options.dark == "median" and not own.keys() >= paths.keys() else None)
        for k in range(0, len(todo), _CHUNK_FRAMES):
            jobs.append(_Job(cam, todo[k : k + _CHUNK_FRAMES], median, img.shape, str(img.dtype), str(reference),
                             options))
    return jobs


def detect_frame(image: np.ndarray, dark: np.ndarray | None, options: DetectOptions, camera: str = "",
                 frame: str = "", check_color: bool = False) -> pa.Table:
    """The candidates of one frame with the session's options.

    A frame whose three channels are equal (and its laser-off frame's) is detected as the grey
    frame it is (:func:`~scanrig.laser.image.prepare_image`).

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8 or uint16 array
        The frame, DN.
    dark : array like ``image`` or None
        Its laser-off frame.
    options : DetectOptions
    camera, frame : str
        Written into every row.
    check_color : bool
        Run the detectors' own check of the laser's colour (the session compares the colours once
        per camera instead, :func:`colour_mismatches`).

    Returns
    -------
    pyarrow.Table
        ``traces.parquet`` rows.

    Raises
    ------
    LaserColourError
        With ``check_color``, as :func:`~scanrig.laser.colour_check.check_laser_colour`.

    Warns
    -----
    BrightSceneWarning
        The detector's, naming ``camera`` and ``frame``.
    """
    from scanrig.laser.spots import detect_spots
    from scanrig.laser.stripes import detect_stripe

    detect, scan = (detect_spots, {}) if options.mode == "spot" else (detect_stripe, {"direction": options.direction})
    with _bright_scene_caught() as messages:
        table = detect(image, color=options.color, dark=dark, roi=options.roi, k_detect=options.k_detect,
                       saturation_level=options.saturation_level, camera=camera, frame=frame,
                       check_color=check_color, **scan)
    for message in messages:
        warnings.warn(BrightSceneWarning(f"camera {camera!r} frame {frame!r}: {message}"), stacklevel=2)
    return table


@contextmanager
def _bright_scene_caught() -> Iterator[list[str]]:
    """Catch the :class:`~scanrig.laser.bright_scene.BrightSceneWarning` issued within the block
    (each one, also a text shown before); the yielded list holds their messages once the block has
    run to its end, and the other warnings caught are issued again then."""
    messages: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", BrightSceneWarning)
        yield messages
    for w in caught:
        if issubclass(w.category, BrightSceneWarning):
            messages.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


@dataclass
class _JobResult:
    """A chunk's rows and the messages of its :class:`~scanrig.laser.bright_scene.BrightSceneWarning`
    (a worker's warnings do not reach the calling process by themselves)."""

    table: pa.Table
    warnings: list[str]


def _run_job(job: _Job):
    """Detect in a chunk of frames (runs in a worker). Returns a :class:`_JobResult`, or (path,
    reason) on bad input."""
    path, read_dark, dark = None, None, job.dark_image
    try:
        out = []
        with _bright_scene_caught() as messages:
            for stem, path, dark_path in job.frames:
                img = read_image(path)
                if dark_path != read_dark:  # the camera's laser-off frame is read once
                    read_dark, dark = dark_path, job.dark_image if dark_path is None else read_image(dark_path)
                for file, image, what in ((path, img, "frame"), (dark_path, dark, "laser-off frame")):
                    if file is not None and (image.shape != job.shape or str(image.dtype) != job.dtype):
                        return (file, f"{what} is {describe_image(image.shape, image.dtype)} but "
                                      f"{Path(job.reference).name} of camera {job.camera!r} is "
                                      f"{describe_image(job.shape, job.dtype)}")
                out.append(detect_frame(img, dark, job.options, job.camera, stem))
    except FileFormatError as exc:
        return (str(exc.path), exc.reason)
    except InputError as exc:
        return (path, str(exc))
    return _JobResult(pa.concat_tables(out) if out else empty_table(), messages)


def _write(session: Session, cameras: list[str], tables: list[pa.Table], finished, options) -> pa.Table:
    """Concatenate, order canonically and write ``traces.parquet`` atomically; while no frame has a
    candidate nothing is written (an earlier file stays as it was)."""
    table = pa.concat_tables(tables)
    if not len(table):
        return table
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


def colour_mismatches(root: str | Path, options: DetectOptions, table: pa.Table) -> list[str]:
    """One line per camera whose frames show a laser of another colour than ``options.color``.

    Each camera's frame where ``options.color`` found the most laser light (its middle frame where
    it found none) is detected again, with its laser-off frame if any (its own, else the camera's).
    A colour laser is checked as the detectors check it (:func:`_detector_line`), and the colour
    that check names is named. A grey laser's frame is detected in red, green and blue too: a
    colour that finds more than :data:`~scanrig.laser.colour_check.FEWER_FACTOR` times grey's light
    (:func:`_laser_light`; with a rank-0 stripe candidate on at least ``_LEAST_STRIPE_LINES`` scan
    lines) is named (:func:`~scanrig.laser.colour_check.colour_shown`), else one that finds more
    than that factor times the light of each other colour
    (:func:`~scanrig.laser.colour_check.one_colour`), unless grey's scene reaches the clip level
    (:class:`~scanrig.laser.bright_scene.BrightSceneWarning`, issued by the detection), where the
    white core of a beam of any colour shows in every colour. Grey frames are not checked. Costs
    one to four detections of one frame per colour camera.

    Parameters
    ----------
    root : path
        Session folder.
    options : DetectOptions
        The options ``table`` was detected with.
    table : pyarrow.Table
        The session's detections (:func:`detect_session`).

    Returns
    -------
    list of str
        ``"cam0: no red laser in <frame path>; the frames show a blue one: use --color blue (or
        laser_color = 'blue' in session.toml)"``, or ``"cam0: red finds 12 times less laser light
        than blue in <frame path>; ..."``.
    """
    session = Session(root)
    light = _laser_light(table, options.mode)
    lines = []
    for camera in session.camera_names("scan"):
        paths = session.image_paths("scan", camera)
        found = {frame: total for (cam, frame), total in light.items() if cam == camera}
        stem = max(found, key=found.get) if found else list(paths)[len(paths) // 2]
        dark_path = session.frame_dark_paths(camera).get(stem, session.dark_path(camera))
        line = _colour_line(camera, paths[stem], read_image(paths[stem]),
                            None if dark_path is None else read_image(dark_path), options)
        lines += [line] if line else []
    return lines


def exposure_mismatches(root: str | Path) -> list[str]:
    """One line per camera whose laser-off frame was taken at another exposure than its frames.

    Each camera's first scan frame with a laser-off file (its own, else the camera's) is compared
    with that file (:func:`~scanrig.laser.exposure.exposure_gains`). Where a channel's gain departs
    from 1 (:func:`~scanrig.laser.exposure.mismatched`), the detection scaled the
    laser-off frames to their frames' exposure (:func:`~scanrig.laser.exposure.exposure_matched`);
    a line says so, and that the camera's automatic exposure or white balance is on. Where the
    gain varies from row to row (flicker bands, :func:`~scanrig.laser.exposure.row_gains`), the
    line says instead that it was matched row by row, over which range of brightness, and how to
    take frames without the bands. Frames of another size than their laser-off file are left to
    the detection's own error.

    Parameters
    ----------
    root : path
        Session folder.

    Returns
    -------
    list of str
        ``"cam0: the laser-off frame <path> is 1.25 times as bright as <frame path> (red 1.25, green
        1.24, blue 1.25): scaled to the frame's before it is subtracted; ..."`` or ``"cam0: the
        laser-off frame <path> is 0.83 to 1.25 times as bright as <frame path> from row to row ..."``.
    """
    session = Session(root)
    lines = []
    for camera in session.camera_names("scan"):
        paths, own = session.image_paths("scan", camera), session.frame_dark_paths(camera)
        stem = next((stem for stem in paths if stem in own), next(iter(paths), None))
        dark_path = own.get(stem, session.dark_path(camera))
        if stem is None or dark_path is None:
            continue
        image, dark = grey_frames(read_image(paths[stem]), read_image(dark_path))
        if image.shape != dark.shape or image.dtype != dark.dtype:
            continue
        by_row = row_gains(image, dark)
        if by_row is not None:  # flicker bands: the line gives their range of brightness
            brightness = 1.0 / np.median(by_row, axis=1)
            lines.append(f"{camera}: the laser-off frame {dark_path} is {brightness.min():.2f} to "
                         f"{brightness.max():.2f} times as bright as {paths[stem]} from row to row (flicker bands "
                         "of a rolling shutter under mains-powered light): scaled row by row before it is "
                         "subtracted; light the scene with a steady lamp, or set the exposure time to whole "
                         "periods of the flicker (10 ms under 50 Hz mains, 8.3 ms under 60 Hz)")
            continue
        gains = exposure_gains(image, dark)
        if mismatched(gains).any():
            brightness = 1.0 / gains
            names = CHANNEL_COLOURS if brightness.size == 3 else ("grey",)
            lines.append(f"{camera}: the laser-off frame {dark_path} is {np.median(brightness):.2f} times as bright "
                         f"as {paths[stem]} ({', '.join(f'{n} {b:.2f}' for n, b in zip(names, brightness))}): "
                         "scaled to the frame's before it is subtracted; automatic exposure or white balance is on, "
                         "set both by hand to take the two frames alike")
    return lines


def _colour_line(camera: str, path: Path, image: np.ndarray, dark: np.ndarray | None,
                 options: DetectOptions) -> str | None:
    """:func:`colour_mismatches`' line for the frame ``path`` of ``camera`` (its image and laser-off
    frame), or None."""
    if options.color != "grey":
        return _detector_line(camera, path, image, dark, options)
    light_with = functools.cache(functools.partial(_frame_light, image, dark, options))
    # the frames' own BrightSceneWarning was issued by the detection: none again here
    with _bright_scene_caught() as messages:
        light_with(options.color)
    if messages:  # grey finds little whatever the laser's:
        return None  # a colour's white cores are no evidence
    with _bright_scene_caught():
        best = colour_shown(image, options.color, light_with, least=0.0)
        if best is not None:
            times = light_with(best) / light_with("grey") if light_with("grey") else float("inf")
            return _other_colour_line(camera, path, "grey", best, times)
        laser = one_colour(image, light_with)
    if laser is None:
        return None
    others = max(light_with(colour) for colour in CHANNEL_COLOURS if colour != laser)
    how = ("the other colours find none" if others == 0 else
           f"{light_with(laser) / others:.0f} times the light of the other colours")
    return (f"{camera}: the laser in {path} is {laser} ({how}), detected as grey on the frames' luma: "
            f"{colour_advice(laser)}")


def _detector_line(camera: str, path: Path, image: np.ndarray, dark: np.ndarray | None,
                   options: DetectOptions) -> str | None:
    """The line for a colour laser: the colour the detectors' own check names
    (:func:`~scanrig.laser.colour_check.check_laser_colour`), or None.

    That check counts only candidates of at least half the clip level, and a clipped one in its
    own colour whatever its fitted peak; the peaks summed over every scan line
    (:func:`_frame_light`) do not tell a beam clipped far past full scale, whose colour difference
    is small in its white core, from texture: without a laser-off frame, green finds twice red's
    summed peaks on the rendered red stripe 8 times past full scale, and with red clipped at
    217 DN by white balance red finds a third of green's."""
    try:
        with _bright_scene_caught():  # the frames' own were issued by the detection: none again here
            detect_frame(image, dark, options, check_color=True)
    except LaserColourError as exc:
        return _other_colour_line(camera, path, options.color, exc.shown, exc.times)
    return None


def _other_colour_line(camera: str, path: Path, asked: str, shown: str, times: float) -> str:
    """``"cam0: red finds 5 times less laser light than green in <path>; the frames show a green one:
    use --color green ..."``; ``times`` is ``inf`` where ``asked`` finds none."""
    what = (f"no {asked} laser in {path}" if times == float("inf") else
            f"{asked} finds {times:.0f} times less laser light than {shown} in {path}")
    return f"{camera}: {what}; the frames show a {shown} one: {colour_advice(shown)}"


def _frame_light(image: np.ndarray, dark: np.ndarray | None, options: DetectOptions, colour: str) -> float:
    """The laser light ``colour`` finds in a frame (:func:`_laser_light`), DN; 0 when it has a
    rank-0 candidate on fewer than ``_LEAST_STRIPE_LINES`` scan lines (stripes) or no candidate."""
    table = detect_frame(image, dark, dataclasses.replace(options, color=colour))
    lines = np.count_nonzero(table["rank"].to_numpy() == 0) if options.mode == "stripe" else len(table)
    return sum(_laser_light(table, options.mode).values()) if lines >= _LEAST_STRIPE_LINES or (
        options.mode == "spot" and lines) else 0.0


def _laser_light(table: pa.Table, mode: str) -> dict[tuple[str, str], float]:
    """``(camera, frame) -> `` the fitted peaks of its candidates summed, DN: each scan line's
    rank-0 one (stripes: one stripe crosses a line once) or all (spots: a frame may hold several).

    The right colour's light is 18 times the best other colour's on the Ciclop bust frame's stripe
    (181 with the laser-off frame), 22 times on a rendered grid of red spots with its laser-off
    frame (2.3 without), where the brightest spot's alone is only 2.8 times."""
    if mode == "stripe":
        table = table.filter(pc.equal(table["rank"], 0))
    sums = table.group_by(["camera", "frame"]).aggregate([("peak", "sum")])
    return dict(zip(zip(sums["camera"].to_pylist(), sums["frame"].to_pylist()), sums["peak_sum"].to_pylist()))
