"""A single-camera line-laser turntable scanner (as Horus, FabScan and Ciclop build it), simulated.

One camera and one line laser stand still; the laser's sheet of light is vertical and contains the
turntable's axis; the object turns by a known angle between frames, so every frame lights one
profile of it. The scene's objects are given in the object frame, which is the world frame at
turntable angle 0; the axis is the world's +z line through ``scene.center_m``.

Placement (world frame, metres): the camera is the scene's default single camera
(:func:`~scanrig.sim.rigs.default_rig` with ``scene.rig``: ``distance_m`` from ``center_m``,
``elevation_deg`` up, at ``azimuth_deg``); the laser stands as far from ``center_m`` and as high,
``triangulation_deg`` further round in azimuth, aimed at ``center_m``.

Every frame is rendered with the object at its pose (background included, so each frame costs
a full render; the multi-camera sessions of :mod:`scanrig.sim.session_writer` render their
background once). Every frame has its own laser-off frame, as Horus takes one at every step: the
object moves, so one laser-off image for the whole scan would match no frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from scanrig.errors import EstimationError, InputError
from scanrig.geometry import Camera, Rig, RigidTransform
from scanrig.io.object_poses import object_poses_path, write_object_poses
from scanrig.io.rig_file import save_rig
from scanrig.io.session import write_image
from scanrig.parallel import run_indexed
from scanrig.sim.laser import BeamPose, trace_laser
from scanrig.sim.light_plane_shots import write_true_light_plane
from scanrig.sim.pixel_rays import PixelRayTable
from scanrig.sim.render import CameraView
from scanrig.sim.rigs import default_rig
from scanrig.sim.scan_setup import LASER_COLOR
from scanrig.sim.scene import Scene
from scanrig.sim.session_writer import (
    Progress,
    scene_and_source,
    session_folder,
    write_session_toml,
    write_truth_meshes,
    write_truth_tables,
)

#: Azimuth between the camera and the laser around the turntable axis, degrees (Ciclop: 30).
TRIANGULATION_DEG = 30.0
#: Built-in scene made for this rig: a matte object 400 mm from the camera.
TURNTABLE_SCENE = "turntable"
#: Peak of the laser stripe on the target in light-plane shots, as a share of the full well (added
#: to the paper's :data:`~scanrig.sim.calibration_shots.PAPER_FILL`, the sum stays below 1).
LASER_FILL = 0.25


@dataclass(frozen=True)
class TurntableRig:
    """One camera, one fixed laser sheet, and the turntable's axis (world frame).

    Attributes
    ----------
    camera : Camera
    laser : BeamPose
        The sheet: apex ``origin``, central ``direction`` and in-plane ``fan_axis``.
    axis_point_m : ndarray of shape (3,)
        A point of the turntable axis, metres.
    axis_direction : ndarray of shape (3,)
        Unit direction of the axis; positive angles turn counter-clockwise seen from its tip.
    """

    camera: Camera
    laser: BeamPose
    axis_point_m: np.ndarray
    axis_direction: np.ndarray

    def world_from_object(self, angle_rad: float) -> RigidTransform:
        """The object's pose with the turntable at ``angle_rad`` (identity at angle 0)."""
        from scipy.spatial.transform import Rotation

        R = Rotation.from_rotvec(angle_rad * self.axis_direction).as_matrix()
        return RigidTransform(R, self.axis_point_m - R @ self.axis_point_m)


def turntable_rig(scene: Scene, triangulation_deg: float = TRIANGULATION_DEG) -> TurntableRig:
    """The camera, laser and axis of a turntable scan of ``scene`` (placement in the module notes).

    Raises
    ------
    InputError
        If ``triangulation_deg`` is not in (0, 90).
    """
    if not 0 < triangulation_deg < 90:
        raise InputError(f"triangulation_deg must be in (0, 90) degrees, got {triangulation_deg!r}")
    spec = scene.rig
    centre = np.asarray(scene.center_m, dtype=np.float64)
    camera = default_rig(1, centre, spec).cameras[0]
    az, el = np.radians(spec.azimuth_deg + triangulation_deg), np.radians(spec.elevation_deg)
    origin = centre + spec.distance_m * np.array([np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)])
    axis = np.array([0.0, 0.0, 1.0])
    laser = BeamPose.from_any(BeamPose(origin, centre - origin, axis))  # fan made perpendicular, unit
    return TurntableRig(camera, laser, centre, axis)


def turntable_angles(n_frames: int) -> np.ndarray:
    """Turntable angles of ``n_frames`` frames evenly over one turn, radians (frame 0 at 0)."""
    if not isinstance(n_frames, (int, np.integer)) or n_frames < 1:
        raise InputError(f"n_frames must be a positive integer, got {n_frames!r}")
    return 2 * np.pi * np.arange(n_frames) / n_frames


def posed_scene(scene: Scene, world_from_object: RigidTransform) -> Scene:
    """The scene with every object moved by ``world_from_object`` (lights and setup unchanged)."""
    matrix = world_from_object.as_matrix()
    objects = tuple(replace(obj, mesh=obj.mesh.copy().apply_transform(matrix)) for obj in scene.objects)
    return replace(scene, objects=objects)


def render_turntable_frame(rig: TurntableRig, scene: Scene, world_from_object: RigidTransform,
                           table: PixelRayTable, rng: np.random.Generator, dark_rng: np.random.Generator):
    """One noisy laser frame with the object at ``world_from_object``, and the same pose with the
    laser off.

    Parameters
    ----------
    rig : TurntableRig
    scene : Scene
        Objects in the object frame.
    world_from_object : RigidTransform
    table : PixelRayTable
        The camera's ray table (shared by all frames).
    rng : numpy.random.Generator
        Speckle and sensor noise of this frame.
    dark_rng : numpy.random.Generator
        Sensor noise of its laser-off frame.

    Returns
    -------
    image : ndarray of shape (H, W)
        The frame, DN.
    dark : ndarray of shape (H, W)
        The laser-off frame (same pose and exposure), DN.
    trace : LaserTrace
        The laser's hits (world frame) in this frame.
    """
    posed = posed_scene(scene, world_from_object)
    view = CameraView(rig.camera, posed, ray_table=table)
    trace = trace_laser(rig.laser, scene.laser, posed)
    electrons = view.background_e.copy()
    window = view.laser_window(trace, rng)
    if window is not None:
        electrons[window.slices] += window.electrons
    return view.sensor.expose(electrons, rng), view.sensor.expose(view.background_e, dark_rng), trace


def write_laser_on_calibration_poses(out: Path, scene: Scene, rig: TurntableRig, shots: dict, rng: np.random.Generator,
                            workers: int | None = None, progress: Progress | None = None) -> None:
    """Write ``light_plane/<camera>/<shot>.png``: each calibration pose again, with the laser on.

    The target stands where its calibration shot of the same stem shows it (that image is the
    laser-off view of the pose), with the same exposure; the laser's power is set so that its
    stripe peaks :data:`LASER_FILL` of the full well above the white paper, so it does not clip.
    Poses whose target the sheet misses give an image without a stripe.

    Parameters
    ----------
    out : Path
        Session folder.
    scene : Scene
        Lighting, sensor and laser optics (its objects are not rendered).
    rig : TurntableRig
    shots : dict of str to RigidTransform
        ``world_from_target`` by calibration shot stem (:func:`~scanrig.sim.calibration_shots.write_calibration`).
    rng : numpy.random.Generator
        One spawned generator per shot (speckle and noise).
    workers : int, optional
    progress : callable, optional
        ``progress(stage, done, total)``.
    """
    from scanrig.sim.calibration_shots import calibration_sensor, default_target, target_scene

    target = default_target("cube")
    sensor = calibration_sensor(scene)
    stems = list(shots)
    shot_rngs = rng.spawn(len(stems))
    camera = rig.camera
    table = PixelRayTable(camera)
    table.xy  # noqa: B018 - solve the camera's rays once, before forking
    folder = out / "light_plane" / camera.name
    folder.mkdir(parents=True, exist_ok=True)

    def render_shot(i: int) -> None:
        posed = target_scene(target, shots[stems[i]], scene)
        view = CameraView(camera, posed, sensor, ray_table=table)
        electrons = view.background_e.copy()
        window = view.laser_window(trace_laser(rig.laser, scene.laser, posed), shot_rngs[i])
        if window is not None and window.electrons.max() > 0:
            gain = LASER_FILL * sensor.full_well_e / window.electrons.max()
            electrons[window.slices] += gain * window.electrons
        write_image(folder / f"{stems[i]}.png", sensor.expose(electrons, shot_rngs[i]))

    report = (lambda done: progress("light plane", done, len(stems))) if progress else None
    run_indexed(render_shot, len(stems), workers, report)


def simulate_turntable_session(
    out: str | Path,
    scene: Scene | str = TURNTABLE_SCENE,
    n_frames: int = 90,
    rng: np.random.Generator | None = None,
    with_calibration: bool = True,
    n_shots: int = 12,
    target_kind: str = "cube",
    triangulation_deg: float = TRIANGULATION_DEG,
    workers: int | None = None,
    progress: Progress | None = None,
    provenance: dict | None = None,
) -> Path:
    """Render a single-camera turntable line-laser session with its ground truth.

    Written files (besides the layout of DESIGN.md §4)::

        scan/cam0/<frame>.png        one frame per turntable angle
        scan/cam0/dark/<frame>.png   its laser-off frame (the object moves: one per frame)
        scan/object_poses.csv        world_from_object of every frame (the turntable's angles)
        calibration/cam0/<shot>.png, target.toml   (with_calibration; shot 000 at the world origin,
                                     so the calibrated world is the scene's)
        light_plane/cam0/<shot>.png  (with_calibration) the same poses with the laser on
        truth/rig.toml               the true camera
        truth/light_plane.toml       the true laser sheet (world frame; exact, so zero residual)
        truth/meshes/<object>.ply    object meshes in the object frame (the world at angle 0)
        truth/frames.csv             true laser hits of every frame, world frame
        truth/laser.csv              the (fixed) laser sheet of every frame
        truth/target_poses.csv       world_from_target of every calibration shot
        truth/scene.toml             copy of the scene file

    Parameters
    ----------
    out : str or Path
        Session folder to create (may exist; these files are overwritten).
    scene : Scene or str
        Objects in the object frame; a built-in name or a scene file.
    n_frames : int
        Frames, evenly over one turn.
    rng : numpy.random.Generator
        Source of all randomness (noise, speckle, target poses).
    with_calibration : bool
        Also write the calibration target shots, laser off and laser on (for
        ``scanrig calibrate --light-plane``).
    n_shots : int
        Calibration target poses.
    target_kind : {"cube"}
        The calibration target; only the cube can stand at the world origin in view of the camera
        (a flat board there faces down), which makes the calibrated world the scene's.
    triangulation_deg : float
        Azimuth between camera and laser around the axis, degrees.
    workers : int, optional
        Rendering processes (default: the number of CPUs, at most 4).
    progress : callable, optional
        Called as ``progress(stage, done, total)``.
    provenance : dict, optional
        Recorded in ``session.toml`` and ``truth/rig.toml`` (e.g. the seed and command line).

    Returns
    -------
    Path
        The session folder.
    """
    if rng is None:
        raise InputError("simulate_turntable_session needs rng (a numpy.random.Generator)")
    angles = turntable_angles(n_frames)
    if with_calibration and target_kind != "cube":
        raise InputError(f"a turntable session is calibrated with the cube standing on the turntable for shot 000 "
                         f"(the world frame); target kind {target_kind!r} cannot stand there in view, use 'cube'")
    scene, scene_source = scene_and_source(scene)
    if scene.colour is not None:
        raise InputError(f"scene {scene.name!r} has a colour camera; turntable sessions render grey cameras only")
    rig = turntable_rig(scene, triangulation_deg)
    out = session_folder(out)
    progress = progress or (lambda stage, done, total: None)
    provenance = dict(provenance or {})
    frame_rngs = rng.spawn(n_frames)
    calib_rng, light_rng = rng.spawn(2)   # children are keyed by index: adding one keeps the others
    dark_rngs = rng.spawn(n_frames)

    name = rig.camera.name
    truth = out / "truth"
    for folder in (truth / "meshes", out / "scan" / name / "dark"):
        folder.mkdir(parents=True, exist_ok=True)
    if with_calibration:
        from scanrig.sim.calibration_shots import write_calibration

        shots = write_calibration(out, scene, Rig([rig.camera]), n_shots, target_kind, calib_rng, workers, progress)
        if not np.array_equal(next(iter(shots.values())).as_matrix(), np.eye(4)):
            raise EstimationError(f"{out}: the camera does not see the cube standing at the world origin (shot 000), "
                                  "so its calibration would not be in the scene's frame of scan/object_poses.csv; "
                                  "aim the camera at the turntable axis (the scene's center_m)")
        write_laser_on_calibration_poses(out, scene, rig, shots, light_rng, workers, progress)
    stems = [f"{i:05d}" for i in range(n_frames)]
    poses = {stem: rig.world_from_object(a) for stem, a in zip(stems, angles)}
    table = PixelRayTable(rig.camera)
    table.xy  # noqa: B018 - solve the camera's rays once, before forking

    def render_one(i: int):
        image, dark, trace = render_turntable_frame(rig, scene, poses[stems[i]], table, frame_rngs[i], dark_rngs[i])
        write_image(out / "scan" / name / f"{stems[i]}.png", image)
        write_image(out / "scan" / name / "dark" / f"{stems[i]}.png", dark)
        return trace.truth_kind, trace.truth_points

    truth_rows = run_indexed(render_one, n_frames, workers, lambda done: progress("frames", done, n_frames))
    write_object_poses(object_poses_path(out), poses)

    save_rig(Rig([rig.camera]), truth / "rig.toml", metadata={"source": "scanrig simulate (true camera)",
                                                             **provenance},
             comments=["ground truth of a simulated turntable session: the camera that rendered the images"])
    write_true_light_plane(truth / "light_plane.toml", rig.laser, name, "ground truth of a simulated turntable session")
    write_truth_meshes(truth, scene, "object frame (the world frame at turntable angle 0)")
    write_truth_tables(truth, stems, truth_rows, [rig.laser] * n_frames, scene_source)

    settings = {"cameras": [name], "laser_mode": "stripe", "laser_color": LASER_COLOR,
                "created_by": "scanrig simulate --rig turntable"}
    write_session_toml(out, "simulated turntable session", settings, provenance, with_target=bool(with_calibration))
    return out
