"""The scan loop: plan beams, move, grab, store, process, re-plan; resumable at any frame.

``run_scan`` drives any rig that follows the protocol (:mod:`scanrig.scan.protocol`): the
simulator, a replay of a recorded session, real cameras and a G-code positioner. Every frame is
logged by the :class:`~scanrig.scan.store.ScanStore` before the next move, so a crash loses at
most the frame in flight, and ``resume=True`` continues where the log ends with the same plan.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scanrig.errors import ScanrigError
from scanrig.reconstruct.points import PointCloud
from scanrig.scan.planner import History, PlannerConfig, plan_pass
from scanrig.scan.processing import (FrameJob, FramePoints, SerialExecutor, concat_points, frame_jobs,
                                     process_frames)
from scanrig.scan.protocol import Cameras, LaserPositioner, RigError
from scanrig.scan.store import RESUME_HINT, ScanStore, frame_stem

#: Seconds to wait for one synchronised grab before declaring the camera dead.
GRAB_TIMEOUT_S = 30.0


@dataclass
class ScanResult:
    """What a scan produced.

    Attributes
    ----------
    frames : list of FramePoints
        Per-frame points, in frame order.
    reason : str
        Why the scan stopped ("density target reached", "beam budget spent", ...).
    n_passes : int
        Passes planned, the uniform one included.
    """

    frames: list[FramePoints]
    reason: str
    n_passes: int

    @property
    def points(self) -> PointCloud:
        """Every point, in frame order."""
        return concat_points(self.frames)


def run_scan(store: ScanStore, cameras: Cameras, positioner: LaserPositioner, config: PlannerConfig,
             process: Callable[[FrameJob], FramePoints], rng: np.random.Generator, budget: int,
             executor=None, on_frame: Callable[[str, int, int], None] | None = None,
             grab_timeout_s: float | None = GRAB_TIMEOUT_S, capture_dark: bool = True) -> ScanResult:
    """Run (or continue) a scan until the density target or the beam budget is reached.

    Parameters
    ----------
    store : ScanStore
        A new store (:meth:`ScanStore.create`) or an interrupted one (:meth:`ScanStore.open`);
        frames already logged are processed, not captured again.
    cameras : Cameras
        Synchronised cameras; their ``names`` must match the store's cameras.
    positioner : LaserPositioner
        Moves the beam.
    config : PlannerConfig
        Planner settings.
    process : callable
        ``FrameJob -> FramePoints``; picklable when ``executor`` runs in other processes.
    rng : numpy.random.Generator
        Drives the planner. When the store already holds passes its state is *replaced* by the
        state logged after the last pass, so that a resumed scan plans what the first run would have.
    budget : int
        Largest number of beams (frames) in the whole scan.
    executor : SerialExecutor, LocalPoolExecutor or DaskExecutor, optional
        Where frames are processed (default: serially here).
    on_frame : callable, optional
        ``on_frame(stem, n_captured, n_planned)`` after each frame is stored (progress display).
    grab_timeout_s : float or None
        A camera that delivers nothing for this long is declared dead (None: wait for ever, for
        the simulator, whose first frame renders the whole background).
    capture_dark : bool
        Grab a laser-off frame before the first beam (``scan/<camera>/dark.png``, see
        :meth:`ScanStore.add_dark`); ``process`` may subtract it.

    Returns
    -------
    ScanResult

    Raises
    ------
    RigError
        A camera or the positioner failed; the frames logged so far stay valid for resume.
    StoreError
        Writing failed (e.g. a full disk); the frames logged so far stay valid for resume.
    """
    state = store.state
    if list(cameras.names) != list(state.cameras):
        raise RigError(f"the rig's cameras {list(cameras.names)} differ from the scan's {state.cameras}")
    executor = executor or SerialExecutor()
    frames = _process(executor, process, store, 0)
    reason = state.finished
    try:
        if reason is None and capture_dark and not state.has_dark:
            _hardware("the positioner failed switching the laser off", positioner.set_laser, False)
            store.add_dark(_grab(cameras, state.cameras, "the dark frame", grab_timeout_s))
        while reason is None:
            if not state.pending:
                reason = _plan_next(store, config, frames, rng, budget)
                if reason is not None:
                    break
            _hardware("the positioner failed switching the laser on", positioner.set_laser, True)
            first_new = len(state.frames)
            for beam in state.pending:
                stem = frame_stem(len(state.frames))
                _hardware(f"the positioner failed moving to {stem}", positioner.move_to, beam)
                images = _grab(cameras, state.cameras, stem, grab_timeout_s)
                store.add_frame(images)
                if on_frame is not None:
                    on_frame(state.frames[-1], len(state.frames), len(state.beams))
            frames += _process(executor, process, store, first_new)
        if state.finished is None:
            store.finish(reason)
    finally:
        _best_effort_laser_off(positioner)
    return ScanResult(frames, reason, len(state.passes))


def _plan_next(store: ScanStore, config: PlannerConfig, frames: list[FramePoints],
               rng: np.random.Generator, budget: int) -> str | None:
    """Log the next pass, or return why the scan is over."""
    state = store.state
    if state.passes:
        rng.bit_generator.state = state.passes[-1].rng_after
    points = np.concatenate([f.points_m for f in frames] or [np.empty((0, 3))])
    point_beam = np.concatenate([np.full(len(f.points_m), f.index, dtype=np.int64) for f in frames]
                                or [np.empty(0, dtype=np.int64)])   # frame i was taken with beam i
    finite = np.all(np.isfinite(points), axis=1)
    history = History(points[finite], point_beam[finite], state.beams, state.aims_m)
    plan = plan_pass(config, len(state.passes), history, rng, budget - len(state.beams))
    if not plan.beams:
        return plan.reason
    store.add_pass(len(state.passes), plan.beams, plan.aims_m, rng.bit_generator.state)
    return None


def _process(executor, process, store: ScanStore, first: int) -> list[FramePoints]:
    return process_frames(executor, process, frame_jobs(store.frame_paths(), first))


def _rig_error(exc: BaseException, what: str) -> RigError:
    """A :class:`RigError` that says what failed, why, and how to continue."""
    detail = str(exc) if isinstance(exc, ScanrigError) else f"{type(exc).__name__}: {exc}"
    return RigError(f"{what}: {detail}; {RESUME_HINT}")


def _hardware(what: str, call: Callable, *args):
    """Run a rig call; anything it raises becomes a :class:`RigError`."""
    try:
        return call(*args)
    except Exception as exc:  # noqa: BLE001 - any driver failure stops the scan cleanly
        raise _rig_error(exc, what) from exc


def _grab(cameras: Cameras, names: list[str], stem: str, timeout_s: float | None) -> dict[str, np.ndarray]:
    """One synchronised grab with a time limit, checked for every camera.

    The grab runs in a daemon thread: a driver that hangs cannot be interrupted from Python, but
    it must not hang the scan (nor the interpreter's exit).
    """
    box: dict = {}

    def target():
        try:
            box["images"] = cameras.grab()
        except BaseException as exc:  # noqa: BLE001 - handed to the scan thread
            box["error"] = exc

    thread = threading.Thread(target=target, name="scanrig-grab", daemon=True)
    thread.start()
    thread.join(timeout_s)
    if thread.is_alive():
        raise RigError(f"the cameras delivered no frame for {stem} within {timeout_s:g} s; {RESUME_HINT}")
    if "error" in box:
        raise _rig_error(box["error"], f"the cameras failed grabbing {stem}") from box["error"]
    images = box["images"]
    for name in names:
        img = images.get(name) if isinstance(images, dict) else None
        if not isinstance(img, np.ndarray) or img.dtype not in (np.uint8, np.uint16) or img.ndim not in (2, 3):
            raise RigError(f"camera {name!r} delivered no valid image for {stem} "
                           f"(got {type(img).__name__}); {RESUME_HINT}")
    return images


def _best_effort_laser_off(positioner: LaserPositioner) -> None:
    try:
        positioner.set_laser(False)
    except Exception:  # noqa: BLE001 - already failing or finished; the laser state is not data
        pass
