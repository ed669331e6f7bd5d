"""``run_demo``: the whole method on the built-in scene, end to end, with the code a real rig uses.

Stages (each timed; a stage whose input is missing says so instead of pretending):

1. **simulate calibration** — the simulator renders the 20 cm ChArUco cube in random poses into
   ``calibration/<camera>/`` and keeps its truth apart (``truth/``: true cameras, meshes, poses).
2. **calibrate** — :func:`scanrig.calibration.calibrate_session` (detection, bundle adjustment,
   uncertainty) writes ``rig.toml`` and ``calibration_report/``. Its world frame is the cube's
   frame in the reference shot; like a real rig whose reference cube pose is surveyed, the demo
   maps it to the scene frame with that shot's recorded pose (``truth/target_poses.csv``), so
   that the laser head, the region of interest and the truth share one frame.
3. **scan** — the adaptive loop (:func:`scanrig.scan.loop.run_scan`) drives the simulator's
   :class:`~scanrig.sim.VirtualRig` through the rig protocol, exactly like hardware, processing
   frames with the *calibrated* cameras; frames go to ``scan/``. Stripe mode runs the planner's
   uniform pass through the same protocol (the loop re-plans from spot frames only).
4. **detect** — :func:`scanrig.laser.session_detect.detect_session` → ``traces.parquet``.
5. **reconstruct** — :func:`scanrig.reconstruct.pipeline.reconstruct_session` → ``points.ply``.
6. **filter** — :func:`scanrig.surface.filter_points` and :func:`scanrig.surface.mesh_from_result`
   → ``surface.ply``, ``mesh.ply`` (the files ``scanrig filter`` writes).
7. **evaluate** — distances of ``points.ply`` and ``surface.ply`` to the true meshes.
8. **report** — :func:`scanrig.report.write_report` → ``report.html``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanrig.errors import InputError

MODES = ("spot", "stripe")

#: Progress callback: ``progress(stage, done, total)``; ``total`` None for an unknown length.
Progress = Callable[[str, int, int | None], None]


@dataclass(frozen=True)
class DemoSettings:
    """Sizes of a demo run.

    Parameters
    ----------
    n_cameras : int
    n_shots : int
        Calibration poses of the cube.
    budget : int
        Largest number of laser beams (frames) of the scan.
    spacing_m : float
        Target point spacing of the adaptive scan, metres.
    image_scale : float
        Factor on the simulated cameras' image size and focal length (1 = 1280 x 1024 px).
    cross_validate : bool
        Odd/even cross-validation of the calibration.
    workers : int
        Processes for frame processing and detection.
    """

    n_cameras: int = 3
    n_shots: int = 8
    budget: int = 100
    spacing_m: float = 0.01
    image_scale: float = 1.0
    cross_validate: bool = True
    workers: int = 2

    @classmethod
    def preset(cls, quick: bool, frames: int | None = None, workers: int = 2) -> DemoSettings:
        """The default (``quick=False``) or the test-sized run; ``frames`` overrides the beam budget."""
        base = cls(n_shots=4, budget=80, cross_validate=False,
                   workers=workers) if quick else cls(workers=workers)
        if frames is not None:
            if frames < 1:
                raise InputError(f"frames must be a positive integer, got {frames}")
            base = DemoSettings(**{**base.__dict__, "budget": int(frames)})
        return base


@dataclass
class StageRecord:
    """Outcome of one stage: ``status`` is ``ok``, ``not available: <reason>`` or ``failed: <reason>``."""

    name: str
    status: str = "not run"
    seconds: float = 0.0
    result: str = ""


@dataclass
class DemoSummary:
    """What a demo run produced; every figure computed by the pipeline in this run (None = not reached).

    Attributes
    ----------
    out : Path
        Session folder.
    mode, seed, settings
        The run's parameters.
    stages : list of StageRecord
    calibration_rms_px : float or None
        RMS reprojection error of the calibration.
    n_points : int or None
        Points in ``points.ply``.
    n_rejected : int or None
        Spot candidates rejected by the cross-camera matching (secondary reflections, noise), or
        multi-view stripe pairs rejected as off the light plane.
    rms_error_mm : float or None
        RMS distance of ``points.ply`` to the true surface, millimetres.
    surface_rms_error_mm : float or None
        The same for ``surface.ply``.
    wall_s : float
        Wall time of the whole run, seconds.
    """

    out: Path
    mode: str
    seed: int
    settings: DemoSettings
    stages: list[StageRecord] = field(default_factory=list)
    calibration_rms_px: float | None = None
    n_points: int | None = None
    n_rejected: int | None = None
    rms_error_mm: float | None = None
    surface_rms_error_mm: float | None = None
    wall_s: float = 0.0

    @property
    def ok(self) -> bool:
        """Every stage succeeded."""
        return all(s.status == "ok" for s in self.stages)

    def figures(self) -> list[tuple[str, str]]:
        """``(quantity, value)`` rows of the headline figures ("not reached" when a stage did not run)."""
        def show(value, fmt):
            return "not reached" if value is None else fmt.format(value)

        return [("calibration RMS reprojection error", show(self.calibration_rms_px, "{:.4f} px")),
                ("points (points.ply)", show(self.n_points, "{}")),
                ("laser candidates rejected (reflections, noise)", show(self.n_rejected, "{}")),
                ("RMS error of points.ply against the truth", show(self.rms_error_mm, "{:.4f} mm")),
                ("RMS error of surface.ply against the truth", show(self.surface_rms_error_mm, "{:.4f} mm")),
                ("mode, seed", f"{self.mode}, {self.seed}"),
                ("total wall time", f"{self.wall_s:.1f} s")]


def run_demo(out: str | Path = "scanrig-demo", *, mode: str = "spot", seed: int = 0, quick: bool = False,
             frames: int | None = None, workers: int = 2, settings: DemoSettings | None = None,
             progress: Progress | None = None) -> DemoSummary:
    """Run the whole method on the default scene into ``out`` (see the module docstring).

    Parameters
    ----------
    out : str or Path
        Session folder to create; must not already hold a scan.
    mode : {"spot", "stripe"}
    seed : int
        Seeds every random choice (image noise, cube poses, planner, report subsample).
    quick : bool
        A smaller run (4 cube poses, 80 beams) for tests.
    frames : int, optional
        Beam budget of the scan (default 100, quick 80).
    workers : int
        Processes for frame processing and detection.
    settings : DemoSettings, optional
        Every size explicitly (``quick``, ``frames`` and ``workers`` are then ignored).
    progress : callable, optional
        ``progress(stage, done, total)``.

    Returns
    -------
    DemoSummary
    """
    if mode not in MODES:
        raise InputError(f"mode must be one of {MODES}, got {mode!r}")
    out = Path(out)
    if (out / "scan").exists():
        raise InputError(f"{out} already holds a scan; give a new --out folder or delete it")
    settings = settings or DemoSettings.preset(quick, frames, workers)
    progress = progress or (lambda stage, done, total: None)
    run = _Run(out, mode, seed, settings, progress)
    start = time.perf_counter()
    for name, step, needs in (("simulate calibration", run.simulate_calibration, ()),
                              ("calibrate", run.calibrate, ("simulate calibration",)),
                              ("scan", run.scan, ("calibrate",)),
                              ("detect", run.detect, ("scan",)),
                              ("reconstruct", run.reconstruct, ("detect",)),
                              ("filter", run.filter, ("reconstruct",)),
                              ("evaluate", run.evaluate, ("reconstruct",)),
                              ("report", run.report, ())):
        run.stage(name, step, needs)
    run.summary.wall_s = time.perf_counter() - start
    return run.summary


class _Run:
    """State shared by the stages of one demo run."""

    def __init__(self, out: Path, mode: str, seed: int, settings: DemoSettings, progress: Progress):
        self.out, self.mode, self.settings, self.progress = out, mode, settings, progress
        self.summary = DemoSummary(out, mode, seed, settings)
        # Independent streams per stage, so that changing one stage's size leaves the others' draws alone.
        self.rng_calibration, self.rng_scan_noise, self.rng_planner, self.rng_filter, self.rng_report = \
            np.random.default_rng(seed).spawn(5)
        self.scene = self.true_rig = self.rig = None

    def stage(self, name: str, step: Callable[[], str], needs: tuple[str, ...]) -> None:
        record = StageRecord(name)
        self.summary.stages.append(record)
        done = {s.name: s.status for s in self.summary.stages}
        missing = [n for n in needs if done.get(n) != "ok"]
        if missing:
            record.status = f"not available: needs {', '.join(missing)}"
            return
        self.progress(name, 0, None)
        start = time.perf_counter()
        try:
            record.result = step()
            record.status = "ok"
        except _NotAvailable as exc:
            record.status = f"not available: {exc}"
        except ModuleNotFoundError as exc:
            own = (exc.name or "").startswith("scanrig.")
            record.status = f"not available: {exc.name} is not built yet" if own else f"failed: {exc}"
        except Exception as exc:  # noqa: BLE001 - a failed stage is reported, the others still run
            record.status = f"failed: {type(exc).__name__}: {exc}"
        record.seconds = time.perf_counter() - start

    # --- stages -------------------------------------------------------------------------------
    def simulate_calibration(self) -> str:
        import tomli_w

        from scanrig.io.atomic import write_bytes_atomic, write_text_atomic
        from scanrig.io.rig_file import save_rig
        from scanrig.sim import load_scene
        from scanrig.sim.calibration_shots import write_calibration
        from scanrig.sim.scan_setup import LASER_COLOR, scene_rig

        s = self.settings
        self.scene = load_scene("default")
        self.true_rig = scene_rig(self.scene, s.n_cameras, s.image_scale)
        (self.out / "truth" / "meshes").mkdir(parents=True, exist_ok=True)
        save_rig(self.true_rig, self.out / "truth" / "rig.toml", metadata={"source": "scanrig demo (true cameras)"},
                 comments=["ground truth of the demo: the cameras that rendered the images"])
        for obj in self.scene.objects:
            write_bytes_atomic(self.out / "truth" / "meshes" / f"{obj.name}.ply",
                               obj.mesh.export(file_type="ply", encoding="binary"))
        settings = {"cameras": self.true_rig.names, "laser_mode": self.mode, "laser_color": LASER_COLOR,
                    "target": "target.toml", "seed": self.summary.seed, "created_by": "scanrig demo"}
        write_text_atomic(self.out / "session.toml", "# scanrig demo session; ground truth in truth/\n"
                          + tomli_w.dumps(settings))
        write_calibration(self.out, self.scene, self.true_rig, s.n_shots, "cube", self.rng_calibration,
                          workers=s.workers,
                          progress=lambda stage, done, total: self.progress("simulate calibration", done, total))
        w, h = self.true_rig.cameras[0].width, self.true_rig.cameras[0].height
        return f"{s.n_shots} cube poses x {s.n_cameras} cameras ({w}x{h} px)"

    def calibrate(self) -> str:
        from scanrig.calibration import calibrate_session
        from scanrig.io.rig_file import load_rig_info, save_rig

        def factory(total):
            count = [0]

            def advance():
                count[0] += 1
                self.progress("calibrate", count[0], total)
            return advance

        result = calibrate_session(self.out, cross_validate=self.settings.cross_validate,
                                   command_line="scanrig demo", progress_factory=factory)
        reference = result.bundle.obs.shot_names[result.init.reference_shot]
        scene_from_calib = _target_pose(self.out / "truth" / "target_poses.csv", reference)
        rig, info, metadata = load_rig_info(self.out / "rig.toml")
        cams = [c.with_pose(c.cam_from_world @ scene_from_calib.inverse()) for c in rig.cameras]
        from scanrig.geometry import Rig

        self.rig = Rig(cams)
        metadata["world_frame"] = (f"scene frame: the cube frame at shot {reference!r} mapped by that shot's "
                                   "surveyed pose (truth/target_poses.csv)")
        save_rig(self.rig, self.out / "rig.toml", info, metadata,
                 comments=[f"scanrig demo calibration: RMS reprojection error {metadata.get('rms_px')} px"])
        self.summary.calibration_rms_px = float(result.bundle.rms_px())
        return f"RMS {self.summary.calibration_rms_px:.3f} px, {int(result.bundle.inliers.sum())} target points"

    def scan(self) -> str:
        from scanrig.scan.planner import PlannerConfig
        from scanrig.scan.store import ScanStore
        from scanrig.sim import VirtualRig
        from scanrig.sim.scan_setup import LASER_COLOR, laser_stations, scene_roi

        s = self.settings
        roi_min, roi_max = scene_roi(self.scene)
        config = PlannerConfig(spacing_m=s.spacing_m, roi_min_m=tuple(roi_min), roi_max_m=tuple(roi_max),
                               stations_m=tuple(tuple(p) for p in laser_stations(self.scene)),
                               stripe=self.mode == "stripe")
        store = ScanStore.create(self.out, self.true_rig.names, {"budget": s.budget, "seed": self.summary.seed,
                                                                 "laser_color": LASER_COLOR,
                                                                 "planner": config.to_dict()})
        virtual = VirtualRig(self.scene, self.true_rig, self.rng_scan_noise)
        virtual.set_laser(False)
        store.add_dark(virtual.grab())
        if self.mode == "spot":
            return self._adaptive_scan(store, virtual, config)
        return self._uniform_scan(store, virtual, config)

    def _adaptive_scan(self, store, virtual, config) -> str:
        from scanrig.scan.loop import run_scan
        from scanrig.scan.processing import SpotProcessor, make_executor
        from scanrig.sim.scan_setup import LASER_COLOR

        s = self.settings
        process = SpotProcessor(self.rig, color=LASER_COLOR, dark=store.dark_paths())
        with make_executor(None, s.workers) as executor:
            result = run_scan(store, virtual, virtual, config, process, self.rng_planner, s.budget,
                              executor=executor,
                              on_frame=lambda stem, done, planned: self.progress("scan", done, s.budget))
        return f"adaptive: {len(store.state.frames)} frames, {result.n_passes} passes ({result.reason})"

    def _uniform_scan(self, store, virtual, config) -> str:
        """The planner's uniform pass through the rig protocol: the loop re-plans from spot frames only."""
        from scanrig.scan.planner import History, plan_pass

        plan = plan_pass(config, 0, History.empty(), self.rng_planner, self.settings.budget)
        store.add_pass(0, plan.beams, plan.aims_m, self.rng_planner.bit_generator.state)
        virtual.set_laser(True)
        for i, beam in enumerate(plan.beams):
            virtual.move_to(beam)
            store.add_frame(virtual.grab())
            self.progress("scan", i + 1, len(plan.beams))
        virtual.set_laser(False)
        store.finish("uniform stripe pass done")
        return f"uniform stripe pass: {len(plan.beams)} frames (adaptive re-planning is for spot frames only)"

    def detect(self) -> str:
        from scanrig.io.session import Session
        from scanrig.laser.session_detect import detect_session, options_from_session
        from scanrig.sim.scan_setup import LASER_COLOR

        options = options_from_session(Session(self.out), self.mode, LASER_COLOR)
        table = detect_session(self.out, options, workers=self.settings.workers,
                               progress=lambda done, total: self.progress("detect", done, total))
        return f"{table.num_rows} candidates"

    def reconstruct(self) -> str:
        from scanrig.reconstruct.pipeline import reconstruct_session

        info = reconstruct_session(self.out, comments=(f"seed: {self.summary.seed}", "scanrig demo"))
        self.summary.n_points = int(info["points"])
        # Spots: candidates the cross-camera matching left out; stripes: multi-view pairs off the light plane.
        self.summary.n_rejected = int(info["n_candidates"] - info["n_candidates_used"] if self.mode == "spot"
                                      else info["pairs_off_plane"])
        return (f"{info['points']} points from {info['frames']} frames; "
                f"{self.summary.n_rejected} {'candidates' if self.mode == 'spot' else 'stripe pairs'} rejected")

    def filter(self) -> str:
        from scanrig.io.filter_files import write_filter_files
        from scanrig.io.ply import read_points_with_sigma
        from scanrig.surface import filter_points, mesh_from_result
        from scanrig.surface.filter import MIN_POINTS

        xyz, point_sigma = read_points_with_sigma(self.out / "points.ply")
        if len(xyz) < MIN_POINTS:
            raise _NotAvailable(f"{len(xyz)} points are too few for the surface fit (< {MIN_POINTS})")
        result = filter_points(xyz, rng=self.rng_filter, point_sigma=point_sigma)
        vertices, faces = mesh_from_result(result)
        # The same files as `scanrig filter`: one surface.ply vertex per input point, in order.
        write_filter_files(self.out, result, vertices, faces,
                           [f"scanrig demo filter, seed {self.summary.seed}", "units m"])
        return f"{int(result.inlier.sum())} of {len(xyz)} points kept, mesh of {len(faces)} triangles"

    def evaluate(self) -> str:
        from scanrig.reconstruct.evaluate import distance_statistics, load_truth_surface
        from scanrig.reconstruct.points import read_points
        from scanrig.report.session_report import surface_inliers

        distance = load_truth_surface(self.out / "truth")
        cloud, _ = read_points(self.out / "points.ply")
        stats = distance_statistics(distance(cloud.p_world))
        self.summary.rms_error_mm = stats["rms_m"] * 1e3
        text = f"points.ply RMS {self.summary.rms_error_mm:.4f} mm"
        surface = self.out / "surface.ply"
        if surface.is_file():
            self.summary.surface_rms_error_mm = distance_statistics(distance(surface_inliers(surface)))["rms_m"] * 1e3
            text += f"; surface.ply RMS {self.summary.surface_rms_error_mm:.4f} mm"
        return text

    def report(self) -> str:
        from scanrig.report import write_report

        rows = [("demo stage: " + s.name, f"{s.status} ({s.seconds:.1f} s) {s.result}")
                for s in self.summary.stages if s.name != "report"]
        path = write_report(self.out, rng=self.rng_report, summary=[*rows, ("demo seed", str(self.summary.seed))],
                            progress=lambda section: self.progress("report", 0, None))
        return str(path.name)


class _NotAvailable(Exception):
    """A stage that this build cannot run (said plainly in the summary, never faked)."""


def _target_pose(path: Path, shot: str):
    """``world_from_target`` of one shot from the simulator's ``target_poses.csv``."""
    from scanrig.errors import FileFormatError
    from scanrig.geometry import RigidTransform

    for line in path.read_text().splitlines()[1:]:
        stem, *values = line.split(",")
        if stem == shot:
            v = np.array(values, dtype=np.float64)
            return RigidTransform(v[:9].reshape(3, 3), v[9:12])
    raise FileFormatError(path, f"no pose for shot {shot!r}")
