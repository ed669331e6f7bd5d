"""Per-frame processing (detect the laser trace, triangulate) and the executors that run it.

A frame is processed independently of every other frame, so frames are farmed out: to a local
process pool by default, or to a Dask distributed cluster (``scanrig scan --scheduler ADDRESS``).
Every executor returns results in the order of the jobs, so the points do not depend on where or
in which order the work ran.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry import Rig
from scanrig.reconstruct.points import PointCloud

#: Modules the local pool's fork server imports once for all workers.
PRELOAD = ["numpy", "cv2", "scanrig.io.session", "scanrig.geometry"]


@dataclass(frozen=True)
class FrameJob:
    """One frame to process.

    Parameters
    ----------
    index : int
        Frame index (position of the stem in natural order).
    stem : str
        Frame stem, e.g. ``f000012``.
    images : dict of str to Path
        ``{camera: image path}``.
    """

    index: int
    stem: str
    images: dict[str, Path]


@dataclass(frozen=True)
class FramePoints:
    """Points of one frame.

    Attributes
    ----------
    index : int
        The job's frame index.
    stem : str
        The job's frame stem.
    cloud : PointCloud
        The frame's points (``frame`` field = ``index``), world frame, metres.
    """

    index: int
    stem: str
    cloud: PointCloud

    @property
    def points_m(self) -> np.ndarray:
        """(n, 3) float array of the frame's points, world frame, metres."""
        return self.cloud.p_world


def frame_jobs(frames: dict[str, dict[str, Path]], first: int = 0) -> list[FrameJob]:
    """Jobs for ``{stem: {camera: path}}`` (in frame order), skipping the first ``first`` frames."""
    return [FrameJob(i, stem, paths) for i, (stem, paths) in enumerate(frames.items()) if i >= first]


def process_frames(executor, process: Callable[[FrameJob], FramePoints], jobs: Sequence[FrameJob]) -> list[FramePoints]:
    """Run ``process`` on every job with ``executor``; results in job order whatever ran where."""
    return list(executor.map(process, jobs)) if jobs else []


def concat_points(frames: Sequence[FramePoints]) -> PointCloud:
    """All frames' points in one cloud, in frame order."""
    return PointCloud.concatenate(f.cloud for f in frames)


class SerialExecutor:
    """Runs jobs one after the other in this process (tests, debugging, tiny scans)."""

    def map(self, fn: Callable, jobs: Sequence) -> list:
        return [fn(job) for job in jobs]

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class LocalPoolExecutor(SerialExecutor):
    """A local process pool (``forkserver`` start method, safe next to threads).

    The fork server imports numpy and OpenCV once (:data:`PRELOAD`); workers fork from it instead
    of each importing them again.

    Parameters
    ----------
    max_workers : int, optional
        Worker processes (default: the number of CPUs).
    """

    def __init__(self, max_workers: int | None = None):
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(PRELOAD)
        self._pool = ProcessPoolExecutor(max_workers, mp_context=context)

    def map(self, fn: Callable, jobs: Sequence) -> list:
        return list(self._pool.map(fn, jobs))

    def close(self) -> None:
        self._pool.shutdown()


class DaskExecutor(SerialExecutor):
    """Jobs on a Dask distributed cluster.

    Parameters
    ----------
    address : str or distributed.Client
        Scheduler address (``tcp://host:8786``) or a connected client (e.g. of a ``LocalCluster``).
    timeout_s : float
        How long to try to reach the scheduler.
    """

    def __init__(self, address, timeout_s: float = 10.0):
        try:
            from distributed import Client
        except ImportError as exc:
            raise InputError("--scheduler needs dask[distributed]: pip install 'scanrig[dask]'") from exc
        self._own = not isinstance(address, Client)
        try:
            self.client = Client(address, timeout=f"{timeout_s}s") if self._own else address
        except OSError as exc:
            raise InputError(f"cannot reach the Dask scheduler at {address!r}: {exc}") from exc

    def map(self, fn: Callable, jobs: Sequence) -> list:
        futures = self.client.map(fn, list(jobs), pure=False)
        return self.client.gather(futures)

    @property
    def n_workers(self) -> int:
        return len(self.client.scheduler_info()["workers"])

    def close(self) -> None:
        if self._own:
            self.client.close()


def make_executor(scheduler: str | None = None, max_workers: int | None = None):
    """The executor the CLI uses: a Dask client when ``scheduler`` is given, else a local pool.

    ``max_workers == 1`` without a scheduler runs serially in this process.
    """
    if scheduler:
        return DaskExecutor(scheduler)
    if max_workers == 1:
        return SerialExecutor()
    return LocalPoolExecutor(max_workers)


@dataclass(frozen=True)
class SpotProcessor:
    """Detect + triangulate one spot-laser frame: a picklable ``FrameJob -> FramePoints``.

    Every camera's spot candidates (:func:`scanrig.laser.spots.detect_spots`) go to the spot
    reconstruction (:func:`scanrig.reconstruct.spots.reconstruct_spots`), which matches them
    across cameras (rejecting reflections) and triangulates; the same code as
    ``scanrig detect`` + ``scanrig reconstruct``, one frame at a time.

    Parameters
    ----------
    rig : Rig
        Calibrated cameras (their names are the session's camera folders).
    color : str
        Laser colour, as ``detect_spots`` takes it.
    dark : dict of str to Path, optional
        Laser-off frame per camera, subtracted before detection.
    """

    rig: Rig
    color: str = "grey"
    dark: dict = field(default_factory=dict)

    def __call__(self, job: FrameJob) -> FramePoints:
        import pyarrow as pa

        from scanrig.io.session import read_image
        from scanrig.laser.spots import detect_spots
        from scanrig.reconstruct.spots import reconstruct_spots

        tables = []
        for name in self.rig.names:
            if name in job.images:
                dark = read_image(self.dark[name]) if name in self.dark else None
                tables.append(detect_spots(read_image(job.images[name]), color=self.color, dark=dark,
                                           camera=name, frame=job.stem))
        cloud, _, _ = reconstruct_spots(self.rig, pa.concat_tables(tables), [job.stem])
        cloud = PointCloud(cloud.p_world, cloud.sigma, cloud.n_views, cloud.residual_px,
                           np.full(len(cloud), job.index), cloud.flags)
        return FramePoints(job.index, job.stem, cloud)
