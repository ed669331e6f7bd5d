"""``scanrig scan``: the closed scanning loop on a simulated, replayed or real rig, resumable."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def command(
    session: Annotated[Path, typer.Argument(help="Session folder to scan into (created if missing).")],
    sim: Annotated[str | None, typer.Option(help="Scan a simulated scene (built-in name or scene file).")] = None,
    replay: Annotated[Path | None, typer.Option(help="Replay the frames of a recorded session folder.")] = None,
    camera: Annotated[list[str] | None, typer.Option(
        help="Real camera NAME=SOURCE (device index, URL or video file); repeat per camera.")] = None,
    gcode: Annotated[str | None, typer.Option(help="Serial port of a GRBL pan-tilt head (with --camera).")] = None,
    head_mm: Annotated[str | None, typer.Option(help="Pan-tilt pivot X,Y,Z in mm, world frame (with --gcode).")] = None,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Continue an interrupted scan with its recorded settings.")] = False,
    scheduler: Annotated[str | None, typer.Option(
        help="Dask scheduler address (tcp://host:8786) for frame processing.")] = None,
    workers: Annotated[int | None, typer.Option(
        help="Local worker processes (1 = in this process; default: all CPUs).")] = None,
    budget: Annotated[int | None, typer.Option(help="Largest number of beams in the scan. [default: 400]")] = None,
    spacing_mm: Annotated[float | None, typer.Option(
        help="Target point spacing on the surface, mm. [default: 8]")] = None,
    roi_mm: Annotated[str | None, typer.Option(
        help="Region of interest XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX in mm (default: the scene's).")] = None,
    n_cameras: Annotated[int, typer.Option(help="Cameras of the simulated rig.")] = 3,
    sim_scale: Annotated[float, typer.Option(
        help="Image size and focal length factor of the simulated cameras (0.25 = quick).")] = 1.0,
    seed: Annotated[int | None, typer.Option(
        help="Seed of the planner (and of the simulator's noise). [default: 0]")] = None,
):
    """Scan adaptively: uniform beams, then beams perpendicular to under-sampled patches.

    Every frame and beam is stored as it arrives (SESSION/scan/manifest.jsonl). A scan
    stopped by a crash, a rig error or a full disk continues with --resume. Points go to
    SESSION/points.ply.

    Example: scanrig scan scan_demo --sim sphere --budget 60 --spacing-mm 20 --seed 1
    """
    import numpy as np

    from scanrig.cli.progress import stage_progress
    from scanrig.errors import InputError
    from scanrig.io.rig_file import load_rig, save_rig
    from scanrig.io.session import Session
    from scanrig.reconstruct.points import write_points
    from scanrig.scan.loop import GRAB_TIMEOUT_S, run_scan
    from scanrig.scan.planner import PlannerConfig
    from scanrig.scan.processing import SpotProcessor, make_executor
    from scanrig.scan.store import ScanStore, read_state

    sources = [name for name, given in (("--sim", sim), ("--replay", replay), ("--camera", camera)) if given]
    if len(sources) != 1:
        raise InputError("give exactly one rig: --sim SCENE, --replay FOLDER or --camera NAME=SOURCE "
                         f"(got {sources or 'none'})")
    given = {"budget": budget, "spacing_mm": spacing_mm, "roi_mm": roi_mm, "seed": seed}
    source = ({"sim": sim, "sim_scale": sim_scale, "n_cameras": n_cameras} if sim else
              {"replay": str(replay)} if replay else {"camera": list(camera), "gcode": gcode, "head_mm": head_mm})
    if resume:
        settings = read_state(session).config
        if settings.get("source") != source:
            raise InputError(f"the scan in {session} was started on the rig {settings.get('source')}; resume it "
                             f"with the same rig options (got {source})")
        _check_same(settings, {k: v for k, v in given.items() if v is not None}, session)
    else:
        settings = {"budget": budget or 400, "spacing_mm": spacing_mm or 8.0, "roi_mm": roi_mm,
                    "seed": 0 if seed is None else seed, "source": source}
    cameras, positioner, calibrated, planner_defaults, color = _rig(session, sim, replay, camera, gcode, head_mm,
                                                                     n_cameras, sim_scale, settings, resume)
    settings.setdefault("laser_color", color)
    if "planner" not in settings:
        settings["planner"] = PlannerConfig(spacing_m=settings["spacing_mm"] / 1e3, **planner_defaults).to_dict()
    config = PlannerConfig.from_dict(settings["planner"])
    store = ScanStore.open(session) if resume else ScanStore.create(session, cameras.names, settings)
    if sim is not None and not (session / "rig.toml").exists():   # only once the store accepted the folder
        save_rig(calibrated, session / "rig.toml",
                 comments=(f"true cameras of the simulated scene {sim!r} (no calibration)",))
        calibrated = load_rig(session / "rig.toml")   # as a resumed scan will read it
    process = SpotProcessor(calibrated, color=settings["laser_color"], dark=store.dark_paths())
    rng = np.random.default_rng(settings["seed"])
    with make_executor(scheduler, workers) as executor, stage_progress() as progress:
        progress("preparing (dark frame, first beams)", 0, None)
        report = _PassProgress(progress, len(store.state.passes) - bool(store.state.pending))
        result = run_scan(store, cameras, positioner, config, process, rng, settings["budget"], executor=executor,
                          on_frame=report.frame,
                          grab_timeout_s=None if camera is None else GRAB_TIMEOUT_S)
    n_frames = len(store.state.frames)
    out = Session(session).points_path
    stopped = f"scanrig scan: {n_frames} frames, {result.n_passes} passes, stopped: {result.reason}"
    write_points(out, result.points, comments=(f"seed: {settings['seed']}", stopped))
    typer.echo(f"{n_frames} frames in {result.n_passes} passes ({result.reason}); "
               f"{len(result.points)} points -> {out}")


class _PassProgress:
    """Progress of the scanning loop, pass by pass: the pass's frames are grabbed, then processed
    together once its last beam is grabbed.

    Parameters
    ----------
    progress : callable
        ``progress(stage, done, total)`` (:func:`scanrig.cli.progress.stage_progress`).
    n_passes : int
        Passes of the scan already complete (a resumed one).
    """

    def __init__(self, progress, n_passes: int):
        self.progress, self.n_passes, self.first = progress, n_passes, None

    def frame(self, stem: str, done: int, planned: int) -> None:
        """``run_scan``'s ``on_frame``: ``done`` frames of the ``planned`` beams so far."""
        if self.first is None:
            self.n_passes, self.first = self.n_passes + 1, done - 1
        stage = f"pass {self.n_passes}"
        self.progress(f"{stage}: grabbing frames", done - self.first, planned - self.first)
        if done == planned:
            self.progress(f"{stage}: processing frames", 0, None)
            self.first = None


def _check_same(recorded: dict, given: dict, session: Path) -> None:
    """``--resume`` continues with the recorded settings; a different explicit value is an error."""
    from scanrig.errors import InputError

    for key, value in given.items():
        if recorded.get(key) != value:
            raise InputError(f"--{key.replace('_', '-')} {value} differs from the interrupted scan's "
                             f"{recorded.get(key)} (recorded in {session / 'scan' / 'manifest.jsonl'})")


def _rig(session, sim, replay, camera, gcode, head_mm, n_cameras, sim_scale, settings, resume):
    """Cameras, positioner, calibrated rig, planner defaults (ROI, stations) and laser colour."""
    import numpy as np

    from scanrig.errors import InputError
    from scanrig.io.rig_file import load_rig
    from scanrig.io.session import Session

    roi = _roi(settings["roi_mm"])
    if sim is not None:
        from scanrig.sim import VirtualRig, load_scene
        from scanrig.sim.scan_setup import (
            LASER_COLOR,
            laser_stations,
            scene_rig,
            scene_roi,
        )

        scene = load_scene(sim)
        rig = scene_rig(scene, n_cameras, sim_scale)
        rig_path = session / "rig.toml"
        roi = scene_roi(scene) if roi is None else roi
        frames = SeededFrames(VirtualRig(scene, rig, np.random.default_rng(settings["seed"])), settings["seed"],
                              _n_grabbed(session) if resume else 0)
        calibrated = load_rig(rig_path) if rig_path.exists() else rig
        return frames, frames, calibrated, _defaults(roi, laser_stations(scene)), LASER_COLOR
    if replay is not None:
        from scanrig.scan.replay import ReplayRig
        from scanrig.scan.store import read_state

        replayed = ReplayRig(replay)
        recorded = read_state(replay).config.get("planner") if (replay / "scan" / "manifest.jsonl").exists() else None
        if recorded is not None and "planner" not in settings and settings["spacing_mm"] / 1e3 == recorded["spacing_m"]:
            settings["planner"] = recorded                 # same target: replay the recorded plan
        if recorded is None and roi is None:
            raise InputError(f"--roi-mm is needed to replay {replay}: it holds no scan manifest with a plan")
        stations = recorded["stations_m"] if recorded else [np.array(roi[1]) + 0.5]
        roi = roi or (recorded["roi_min_m"], recorded["roi_max_m"])
        color = Session(replay).settings().get("laser_color", "grey")
        return replayed, replayed, load_rig(replay / "rig.toml"), _defaults(roi, stations), color
    from scanrig.scan.cameras import VideoCaptureCameras
    from scanrig.scan.positioners import GcodePositioner, PanTiltHead

    sources = dict(_camera_source(c) for c in camera)
    if gcode is None or head_mm is None or roi is None:
        raise InputError("a real rig needs --gcode PORT, --head-mm X,Y,Z and --roi-mm besides --camera")
    head = np.array(_floats(head_mm, 3, "--head-mm")) / 1e3
    return (VideoCaptureCameras(sources), GcodePositioner(gcode, PanTiltHead(head)), load_rig(session / "rig.toml"),
            _defaults(roi, [head]), "grey")


class SeededFrames:
    """The simulator's virtual rig with per-frame image noise: frame ``i`` draws from ``(seed, i)``.

    A resumed scan starts a new virtual rig; drawing each frame's noise from its own generator
    makes its frames identical to those of an uninterrupted scan (the virtual rig itself draws
    from one generator in grab order).
    """

    def __init__(self, virtual_rig, seed: int, first_grab: int):
        self.virtual_rig, self.seed, self.n_grabs = virtual_rig, seed, first_grab
        self.names = virtual_rig.names

    def move_to(self, beam) -> None:
        self.virtual_rig.move_to(beam)

    def set_laser(self, on: bool) -> None:
        self.virtual_rig.set_laser(on)

    def grab(self):
        import numpy as np

        rng = np.random.default_rng([self.seed, self.n_grabs])
        self.n_grabs += 1
        return self.virtual_rig.grab(rng=rng)


def _n_grabbed(session: Path) -> int:
    """Grabs already stored: the dark frame (if any) and every logged frame."""
    from scanrig.scan.store import read_state

    state = read_state(session)
    return int(state.has_dark) + len(state.frames)


def _defaults(roi, stations) -> dict:
    return {"roi_min_m": tuple(roi[0]), "roi_max_m": tuple(roi[1]),
            "stations_m": tuple(tuple(float(x) for x in s) for s in stations)}


def _roi(text: str | None):
    if text is None:
        return None
    v = [x / 1e3 for x in _floats(text, 6, "--roi-mm")]
    return tuple(v[:3]), tuple(v[3:])


def _floats(text: str, n: int, option: str) -> list[float]:
    from scanrig.errors import InputError

    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        values = []
    if len(values) != n:
        raise InputError(f"{option} must be {n} comma-separated numbers, got {text!r}")
    return values


def _camera_source(text: str) -> tuple[str, int | str]:
    from scanrig.errors import InputError

    name, sep, source = text.partition("=")
    if not sep or not name or not source:
        raise InputError(f"--camera must be NAME=SOURCE (device index, URL or video file), got {text!r}")
    return name, int(source) if source.isdigit() else source
