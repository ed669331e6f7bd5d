"""Light-plane shots: a fixed line laser on the calibration target at several poses, rendered.

The classic single-camera head (Ciclop, Horus, FabScan): a line laser mounted ``baseline_m`` to the
camera's right, its sheet containing the camera's vertical (y) axis and crossing the optical axis
``crossing_m`` in front of the lens, so the stripe is a near-vertical line in the image. The
printed target is placed across the sheet at distances of 0.3-0.6 m (farther when the board would
not fit the image at 0.3 m), tilted 15-30 degrees about the camera's x, y or a diagonal axis in
turn. Each pose is written twice with the same stem: ``calibration/<camera>/<stem>.png`` with the
laser off and ``light_plane/<camera>/<stem>.png`` with it on (RGB from a colour camera, ``.jpg``
when it stores JPEG: :mod:`scanrig.sim.colour`); the true sheet goes to
``truth/light_plane.toml`` (the format of ``light_plane.toml``, scene frame) and the poses to
``truth/light_plane_poses.csv`` (the columns of ``truth/target_poses.csv``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from scanrig.errors import InputError
from scanrig.geometry import RigidTransform
from scanrig.io.atomic import write_text_atomic
from scanrig.sim.calibration_shots import calibration_sensor, target_scene
from scanrig.sim.colour import sensor_rgb, still_frame, write_frame
from scanrig.sim.laser import BeamPose, trace_laser
from scanrig.sim.pixel_rays import PixelRayTable
from scanrig.sim.render import CameraView

#: Laser to the camera's right, metres, and where its sheet crosses the optical axis.
BASELINE_M = 0.12
CROSSING_M = 0.45
#: Target distances from the camera, metres (raised together when the board does not fit).
DISTANCE_RANGE_M = (0.3, 0.6)
#: Largest share of the image's width or height the face-on board may cover.
FILL = 0.85
#: Tilt of the target between poses, degrees.
TILT_RANGE_DEG = (15.0, 30.0)
#: Stems of the shots: ``lp00``, ``lp01`` ...
STEM_PREFIX = "lp"


def laser_sheet(camera, baseline_m: float = BASELINE_M, crossing_m: float = CROSSING_M) -> BeamPose:
    """The fixed sheet of a line laser beside ``camera`` (world frame)."""
    world_from_cam = camera.cam_from_world.inverse()
    origin = world_from_cam.apply(np.array([[baseline_m, 0.0, 0.0]]))[0]
    aim = world_from_cam.apply(np.array([[0.0, 0.0, crossing_m]]))[0]
    return BeamPose.from_any(BeamPose(origin, aim - origin, world_from_cam.R[:, 1]))


def sheet_plane(beam: BeamPose) -> tuple[np.ndarray, float]:
    """The plane ``normal · x = offset`` of a sheet (unit normal, metres)."""
    normal = np.cross(beam.direction, beam.fan_axis)
    normal /= np.linalg.norm(normal)
    return normal, float(normal @ beam.origin)


def write_true_light_plane(path: Path, beam: BeamPose, camera_name: str, source: str) -> None:
    """Write a sheet as an exact plane (zero residual) in the format of ``light_plane.toml``, scene frame."""
    import tomli_w

    normal, offset = sheet_plane(beam)
    doc = {"format_version": 1, "units": "m", "camera": camera_name, "normal": normal.tolist(), "offset_m": offset,
           "centroid_m": beam.origin.tolist(), "axes": [beam.direction.tolist(), beam.fan_axis.tolist()],
           "spread_m2": [1.0, 1.0], "residual_m": 0.0, "n_inliers": 1}
    write_text_atomic(path, f"# {source}: the laser sheet normal . x = offset_m (exact, scene frame)\n"
                      + tomli_w.dumps(doc))


def shot_poses(camera, target, beam: BeamPose, n_shots: int, rng: np.random.Generator) -> list[RigidTransform]:
    """``world_from_target`` of ``n_shots`` poses of a planar target across the sheet.

    Distances spread evenly over :data:`DISTANCE_RANGE_M` (in random order), tilts of
    :data:`TILT_RANGE_DEG` about the camera's x, y and diagonal axes in turn with random signs,
    the board's centre on the sheet at the optical axis' height (within ±20 mm), its print upright
    in the image within ±10 degrees.

    Raises
    ------
    InputError
        If the target is not planar or ``n_shots`` < 2.
    """
    if not target.is_planar or len(target.boards) != 1:
        raise InputError(f"light-plane shots need a planar target (chessboard or charuco), got {target.kind!r}")
    if n_shots < 2:
        raise InputError(f"light-plane shots need at least 2 poses, got {n_shots}")
    board = target.boards[0]
    w, h = board.size_m
    fit_m = max(camera.params[0] * w / camera.width, camera.params[1] * h / camera.height) / FILL
    near = max(DISTANCE_RANGE_M[0], fit_m)
    distances = rng.permutation(np.linspace(near, near + np.ptp(DISTANCE_RANGE_M), n_shots))
    world_from_cam = camera.cam_from_world.inverse()
    normal_cam = camera.cam_from_world.R @ sheet_plane(beam)[0]
    offset_cam = sheet_plane(beam)[1] - sheet_plane(beam)[0] @ world_from_cam.t
    centre_board = np.array([w / 2, h / 2, 0.0])
    centre_target = board.target_from_board.apply(centre_board[None])[0]
    axes = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]]) / np.array([[1.0], [1.0], [np.sqrt(2)]])
    poses = []
    for k, z in enumerate(distances):
        tilt = np.radians(rng.uniform(*TILT_RANGE_DEG)) * rng.choice([-1.0, 1.0])
        spin = np.radians(rng.uniform(-10.0, 10.0))
        R_cam = (Rotation.from_rotvec(tilt * axes[k % 3]) * Rotation.from_rotvec([0.0, 0.0, spin])).as_matrix()
        y = rng.uniform(-0.02, 0.02)
        x = (offset_cam - normal_cam[1] * y - normal_cam[2] * z) / normal_cam[0]
        R_board = world_from_cam.R @ R_cam
        R = R_board @ board.target_from_board.R.T
        t = world_from_cam.apply(np.array([[x, y, z]]))[0] - R @ centre_target
        poses.append(RigidTransform(R, t))
    return poses


def write_light_plane_shots(out: Path, room, rig, target, n_shots: int, rng: np.random.Generator,
                            camera_name: str | None = None, workers: int | None = None, progress=None) -> list[str]:
    """Render light-plane shots of one camera; write images, ``truth/light_plane.toml`` and
    ``truth/light_plane_poses.csv``.

    Parameters
    ----------
    out : Path
        Session folder.
    room : Scene
        Lighting, sensor and laser optics (its objects are not rendered).
    rig : Rig
    target : Target
        Planar; the session's ``target.toml``.
    n_shots : int
    rng : numpy.random.Generator
        Poses, then one spawned generator per shot for its noise and speckle.
    camera_name : str, optional
        The camera with the laser (default: the rig's first).
    workers : int, optional
    progress : callable, optional
        ``progress(stage, done, total)``.

    Returns
    -------
    list of str
        The stems written.
    """
    from scanrig.parallel import run_indexed

    camera = rig[camera_name or rig.names[0]]
    beam = laser_sheet(camera)
    poses = shot_poses(camera, target, beam, n_shots, rng)
    shot_rngs = rng.spawn(n_shots)
    stems = [f"{STEM_PREFIX}{i:02d}" for i in range(n_shots)]
    sensor = calibration_sensor(room)
    table = PixelRayTable(camera)
    table.xy  # noqa: B018 - solve the camera's rays once, before forking
    for folder in (out / "calibration" / camera.name, out / "light_plane" / camera.name, out / "truth"):
        folder.mkdir(parents=True, exist_ok=True)

    def render_shot(i: int) -> None:
        scene = target_scene(target, poses[i], room)
        view = CameraView(camera, scene, sensor, ray_table=table)
        off_rng, on_rng = shot_rngs[i].spawn(2)
        background_e = view.background_e
        off = still_frame(background_e, sensor, room.colour, off_rng)
        write_frame(out / "calibration" / camera.name / stems[i], off, room.colour)
        laser_e = np.zeros_like(background_e)
        window = view.laser_window(trace_laser(beam, room.laser, scene), on_rng)
        if window is not None:
            laser_e[window.slices] += window.electrons
        on = (sensor.expose(background_e + laser_e, on_rng) if room.colour is None
              else sensor_rgb(background_e, laser_e, sensor, room.colour, on_rng))
        write_frame(out / "light_plane" / camera.name / stems[i], on, room.colour)

    report = (lambda done: progress("light plane", done, n_shots)) if progress else None
    run_indexed(render_shot, n_shots, workers, report)
    write_true_light_plane(out / "truth" / "light_plane.toml", beam, camera.name,
                           "ground truth of simulated light-plane shots")
    rows = [",".join([stem, *(repr(float(v)) for v in (*pose.R.ravel(), *pose.t))]) for stem, pose in zip(stems, poses)]
    write_text_atomic(out / "truth" / "light_plane_poses.csv",
                      "\n".join(["shot,r11,r12,r13,r21,r22,r23,r31,r32,r33,tx,ty,tz", *rows]) + "\n")
    return stems
