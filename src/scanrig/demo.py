"""``run_demo``: the whole method on the built-in scene, end to end, with the code a real rig uses.

Stages (each timed; a stage whose input is missing says so instead of pretending):

1. **simulate calibration** — the simulator renders the 20 cm ChArUco cube in random poses into
   ``calibration/<camera>/`` and keeps its truth apart (``truth/``: true cameras, meshes, poses).
2. **calibrate** — :func:`scanrig.calibration.calibrate_session` (detection, bundle adjustment,
   uncertainty) writes ``rig.toml`` and ``calibration_report/``. Its world frame is the cube's
   frame in the reference shot; like a real rig whose reference cube pose is surveyed, the demo
   maps it to the scene frame with that shot's recorded pose (``truth/target_poses.csv``), so
   that the laser head, the region of interest and the truth share one frame.
3. **scan** — the simulator's :class:`~scanrig.sim.VirtualRig` is driven through the rig
   protocol, exactly like hardware; frames go to ``scan/``. Stripe mode (the default) sweeps
   upright laser sheets from the laser head across the scene; spot mode runs the adaptive loop
   (:func:`scanrig.scan.loop.run_scan`), processing frames with the *calibrated* cameras.
4. **detect** — :func:`scanrig.laser.session_detect.detect_session` → ``traces.parquet``.
5. **reconstruct** — :func:`scanrig.reconstruct.pipeline.reconstruct_session` → ``points.ply``.
6. **filter** — :func:`scanrig.surface.filter_points` and :func:`scanrig.surface.mesh_from_result`
   → ``surface.ply``, ``mesh.ply`` (the files ``scanrig filter`` writes).
7. **evaluate** — :func:`scanrig.reconstruct.evaluate.session_accuracy`: the RMS distance of all
   points to the true meshes, before and after the filter (the figures of ``scanrig evaluate``).
8. **inspect** — :func:`scanrig.inspect.inspect_cloud` against the true meshes as the CAD model →
   ``inspection/`` (``inspection.ply``, ``.json``, ``.html``, as ``scanrig inspect`` writes them).
9. **report** — :func:`scanrig.report.write_report` → ``report.html``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanrig.errors import InputError

MODES = ("stripe", "spot")
#: Sheets of the default stripe sweep, and of the quick run.
STRIPE_FRAMES = 100
QUICK_STRIPE_FRAMES = 12
#: Default largest input of the surface filter (see DemoSettings.filter_max_points), and the quick run's.
FILTER_MAX_POINTS = 100_000
QUICK_FILTER_MAX_POINTS = 1500
#: The inspection's tolerance on |deviation| (the stripe reconstruction's precision cut).
INSPECTION_TOLERANCE_M = 1e-4

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
        Frames of the scan: sheets of the stripe sweep, or the beam budget of the adaptive spot scan.
    spacing_m : float
        Target point spacing of the adaptive scan, metres.
    image_scale : float
        Factor on the simulated cameras' image size and focal length (1 = 1280 x 1024 px).
    cross_validate : bool
        Cross-validation of the calibration (halves of the shots calibrated apart).
    workers : int
        Processes for frame processing and detection.
    filter_max_points : int
        Largest input of the surface filter: a larger cloud is filtered through a random
        subsample of this size (the filter's time grows with its input; the mesh is fitted to
        the subsample, the report says so).
    """

    n_cameras: int = 3
    n_shots: int = 8
    budget: int = 100
    spacing_m: float = 0.01
    image_scale: float = 1.0
    cross_validate: bool = True
    workers: int = 2
    filter_max_points: int = FILTER_MAX_POINTS

    @classmethod
    def preset(cls, quick: bool, frames: int | None = None, workers: int = 2, mode: str = "stripe") -> DemoSettings:
        """The default (``quick=False``) or the test-sized run of ``mode``; ``frames`` overrides the budget.

        The budget is the number of frames: beams of the adaptive spot scan, or sheets of the
        stripe sweep (:data:`STRIPE_FRAMES`, quick :data:`QUICK_STRIPE_FRAMES`).
        """
        stripe = mode == "stripe"
        if quick:
            base = cls(n_shots=4, budget=QUICK_STRIPE_FRAMES if stripe else 80, cross_validate=False, workers=workers,
                       filter_max_points=QUICK_FILTER_MAX_POINTS)
        else:
            base = cls(budget=STRIPE_FRAMES if stripe else 100, workers=workers)
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
        RMS distance of every point of ``points.ply`` to the true surface, millimetres
        (:func:`scanrig.reconstruct.evaluate.session_accuracy`, as ``scanrig evaluate`` prints it).
    surface_rms_error_mm : float or None
        The same over the points the filter kept.
    n_filter_removed : int or None
        Points the filter removed.
    coverage : float or None
        Share of the true surface in the cloud's bounding box within 5 mm of a point.
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
    n_filter_removed: int | None = None
    coverage: float | None = None
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
                ("RMS distance to the truth, all points", show(self.rms_error_mm, "{:.4f} mm")),
                ("points the filter removed", show(self.n_filter_removed, "{}")),
                ("RMS distance to the truth, points the filter kept", show(self.surface_rms_error_mm, "{:.4f} mm")),
                ("coverage of the true surface (within 5 mm)",
                 show(None if self.coverage is None else 100 * self.coverage, "{:.1f} %")),
                ("mode, seed", f"{self.mode}, {self.seed}"),
                ("total wall time", f"{self.wall_s:.1f} s")]


def run_demo(out: str | Path = "scanrig-demo", *, mode: str = "stripe", seed: int = 0, quick: bool = False,
             frames: int | None = None, workers: int = 2, settings: DemoSettings | None = None,
             progress: Progress | None = None) -> DemoSummary:
    """Run the whole method on the default scene into ``out`` (see the module docstring).

    Parameters
    ----------
    out : str or Path
        Session folder to create; must not already hold a scan.
    mode : {"stripe", "spot"}
        ``stripe`` (default): a sweep of laser sheets, a dense cloud and its mesh; ``spot``: the
        adaptive spot scan.
    seed : int
        Seeds every random choice (image noise, cube poses, planner, report subsample).
    quick : bool
        A smaller run (4 cube poses; 12 sheets or 80 spot beams; the filter on 1500 points) for tests.
    frames : int, optional
        Frames of the scan (stripe: 100 sheets, quick 12; spot: 100 beams, quick 80).
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
    settings = settings or DemoSettings.preset(quick, frames, workers, mode)
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
                              ("inspect", run.inspect, ("reconstruct",)),
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
        from scanrig.reconstruct.evaluate import SCENE_WORLD_FRAME

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
        metadata["world_frame"] = SCENE_WORLD_FRAME
        metadata["world_frame_from"] = (f"the cube frame at shot {reference!r} mapped by that shot's surveyed pose "
                                        "(truth/target_poses.csv)")
        save_rig(self.rig, self.out / "rig.toml", info, metadata,
                 comments=[f"scanrig demo calibration: RMS reprojection error {metadata.get('rms_px')} px"])
        self.summary.calibration_rms_px = float(result.bundle.rms_px())
        return f"RMS {self.summary.calibration_rms_px:.3f} px, {int(result.bundle.inliers.sum())} target points"

    def scan(self) -> str:
        from scanrig.scan.store import ScanStore
        from scanrig.sim import VirtualRig
        from scanrig.sim.scan_setup import LASER_COLOR

        s = self.settings
        config = self._planner_config() if self.mode == "spot" else None
        plan = {"planner": config.to_dict()} if config else {"sweep": "upright stripe sheets from the laser head"}
        store = ScanStore.create(self.out, self.true_rig.names, {"budget": s.budget, "seed": self.summary.seed,
                                                                 "laser_color": LASER_COLOR, **plan})
        virtual = VirtualRig(self.scene, self.true_rig, self.rng_scan_noise, workers=s.workers)
        virtual.set_laser(False)
        store.add_dark(virtual.grab())
        if config is not None:
            return self._adaptive_scan(store, virtual, config)
        return self._stripe_sweep(store, virtual)

    def _planner_config(self):
        from scanrig.scan.planner import PlannerConfig
        from scanrig.sim.scan_setup import laser_stations, scene_roi

        roi_min, roi_max = scene_roi(self.scene)
        return PlannerConfig(spacing_m=self.settings.spacing_m, roi_min_m=tuple(roi_min), roi_max_m=tuple(roi_max),
                             stations_m=tuple(tuple(p) for p in laser_stations(self.scene)))

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

    def _stripe_sweep(self, store, virtual) -> str:
        """Vertical light sheets from the laser head swept in pan across the scene, rendered on ``workers``.

        The sheets are the simulator's stripe raster (:func:`scanrig.sim.laser.raster_poses`, as
        ``scanrig simulate --mode stripe``): upright, so that they cross the epipolar lines of the
        cameras, which stand side by side at about the head's height. (A sheet fanned sideways,
        as the planner's uniform pass gives, is seen nearly edge-on by those cameras: its stripe
        runs along their epipolar lines and locates few points.) The frames are independent, so they
        are rendered in forked processes, each with its own generator; the store then receives
        them in beam order through the rig protocol, as from hardware.
        """
        from scanrig.scan.protocol import Beam
        from scanrig.sim.laser import raster_poses
        from scanrig.parallel import run_indexed

        n = self.settings.budget
        poses = raster_poses(self.scene.laser, self.scene.center_m, self.scene.radius_m, n, "stripe")
        beams = [Beam(p.origin, p.direction, p.fan_axis) for p in poses]
        centre = np.asarray(self.scene.center_m, np.float64)
        # Aim: the point of each beam's central ray nearest the scene centre.
        aims = np.array([b.origin + b.direction * float((centre - b.origin) @ b.direction) for b in beams])
        frame_rngs = self.rng_scan_noise.spawn(n)
        store.add_pass(0, beams, aims, self.rng_planner.bit_generator.state)

        def render(i: int) -> dict[str, np.ndarray]:
            virtual.move_to(beams[i])
            virtual.set_laser(True)
            return virtual.grab(frame_rngs[i])

        frames = run_indexed(render, n, self.settings.workers, lambda done: self.progress("scan", done, n))
        for images in frames:
            store.add_frame(images)
        store.finish("stripe sweep done")
        return f"stripe sweep: {n} upright sheets from the laser head"

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

        info = reconstruct_session(self.out, seed=self.summary.seed, comments=("scanrig demo",),
                                   workers=self.settings.workers)
        self.summary.n_points = int(info["points"])
        # Spots: candidates the cross-camera matching left out; stripes: multi-view pairs off the light plane.
        self.summary.n_rejected = int(info["n_candidates"] - info["n_candidates_used"] if self.mode == "spot"
                                      else info["pairs_off_plane"])
        return (f"{info['points']} points from {info['frames']} frames; "
                f"{self.summary.n_rejected} {'candidates' if self.mode == 'spot' else 'stripe pairs'} rejected")

    def filter(self) -> str:
        from scanrig.io.filter_files import write_filter_files
        from scanrig.io.ply import read_points_with_sigma
        from scanrig.report.viewer import subsample
        from scanrig.surface import filter_points, mesh_from_result
        from scanrig.surface.filter import MIN_POINTS

        xyz, point_sigma = read_points_with_sigma(self.out / "points.ply")
        if len(xyz) < MIN_POINTS:
            raise _NotAvailable(f"{len(xyz)} points are too few for the surface fit (< {MIN_POINTS})")
        # The filter's time grows with its input: a larger cloud is filtered through a random subsample.
        given = subsample(len(xyz), self.settings.filter_max_points, self.rng_filter)
        result = filter_points(xyz[given], rng=self.rng_filter,
                               point_sigma=None if point_sigma is None else point_sigma[given])
        vertices, faces = mesh_from_result(result)
        subset = f"filter input: {len(given)} of the {len(xyz)} points of points.ply, drawn at random"
        # The files of `scanrig filter`: one surface.ply vertex per point the filter was given, in order.
        write_filter_files(self.out, result, vertices, faces,
                           [f"scanrig demo filter, seed {self.summary.seed}", "units m",
                            *([subset] if len(given) < len(xyz) else [])])
        kept = f"{int(result.inlier.sum())} of {len(given)} points kept"
        return (f"{kept} ({subset})" if len(given) < len(xyz) else kept) + f", mesh of {len(faces)} triangles"

    def evaluate(self) -> str:
        from scanrig.reconstruct.evaluate import session_accuracy

        acc = session_accuracy(self.out / "points.ply", self.out / "truth", rig_path=self.out / "rig.toml",
                               surface_path=self.out / "surface.ply")
        self.summary.rms_error_mm = acc.before["rms_m"] * 1e3
        self.summary.coverage = acc.coverage
        text = f"all {acc.before['n_points']} points: RMS {self.summary.rms_error_mm:.4f} mm"
        if acc.after is not None:
            self.summary.surface_rms_error_mm = acc.after["rms_m"] * 1e3
            self.summary.n_filter_removed = acc.n_removed
            text += f"; the {acc.after['n_points']} the filter kept: RMS {self.summary.surface_rms_error_mm:.4f} mm"
        return text + f"; coverage {100 * acc.coverage:.1f} %"

    def inspect(self) -> str:
        """The scan against the scene's true meshes as its CAD model, as ``scanrig inspect`` does.

        The cloud is already in the scene frame (the surveyed reference pose), so the robust ICP
        starts from the identity instead of the coarse global search; its residual and the
        deviation map go to ``inspection/``.
        """
        import trimesh

        from scanrig.inspect import inspect_cloud, write_inspection
        from scanrig.io.ply import read_points
        from scanrig.report.cloud_sections import INSPECTION_DIR
        from scanrig.report.inspection_page import write_inspection_page

        meshes = [trimesh.load(p, force="mesh", process=False) for p in sorted((self.out / "truth" / "meshes").glob("*.ply"))]
        cad = trimesh.util.concatenate(meshes)
        points = read_points(self.out / "points.ply")
        result = inspect_cloud(points, cad, tolerance_m=INSPECTION_TOLERANCE_M, initial_cad_from_cloud=np.eye(4),
                               seed=self.summary.seed)
        title = "scanrig demo: the scan against the default scene's true meshes as CAD"
        folder = self.out / INSPECTION_DIR
        write_inspection(result, folder, points_m=points, title=title)
        write_inspection_page(result, folder, points_m=points, title=title)
        st = result.stats
        return (f"{INSPECTION_DIR}/: {100 * st.within_tolerance:.1f} % of {st.n_points} points within "
                f"±{INSPECTION_TOLERANCE_M * 1e3:g} mm, deviation RMS {st.rms_m * 1e3:.4f} mm, ICP residual "
                f"{result.alignment.residual_rms_m * 1e3:.4f} mm")

    def report(self) -> str:
        from scanrig.report import write_report

        rows = [("demo stage: " + s.name, f"{s.status} ({s.seconds:.1f} s) {s.result}")
                for s in self.summary.stages if s.name != "report"]
        subject = None
        if self.scene is not None:
            what = "laser sheets swept" if self.mode == "stripe" else "adaptive laser spots (budget)"
            subject = (f"the simulator's default scene ({', '.join(o.name for o in self.scene.objects)}), "
                       f"{self.settings.n_cameras} cameras, {self.settings.budget} {what}")
        path = write_report(self.out, rng=self.rng_report, summary=[*rows, ("demo seed", str(self.summary.seed))],
                            subject=subject, progress=lambda section: self.progress("report", 0, None))
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
