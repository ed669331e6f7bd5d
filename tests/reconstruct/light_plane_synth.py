"""Synthetic light-plane calibrations (a fixed laser sheet on a target at known poses, no rendering),
and the errors of a calibrated plane against a known one.

The camera sits at the world origin (world = camera frame); the laser sheet leaves a point
``BASELINE_M`` to the camera's right, contains the camera's y axis and crosses the optical axis at
``CROSSING_M``, as on a Ciclop/Horus head. Each pose puts a flat target across the sheet; the
stripe is the line where they meet, its pixels observed with noise, and the points come back by
intersecting their rays with the target plane *as the calibration knows it* (with its pose error).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from scanrig.geometry import Camera

BASELINE_M = 0.12
CROSSING_M = 0.45
FOCAL_PX = 1000.0
WIDTH, HEIGHT = 1280, 1024
#: Half-length of the stripe on the target, metres.
HALF_STRIPE_M = 0.09


def camera() -> Camera:
    K = np.array([[FOCAL_PX, 0, WIDTH / 2 - 0.5], [0, FOCAL_PX, HEIGHT / 2 - 0.5], [0, 0, 1.0]])
    return Camera.from_opencv("cam0", K, np.zeros(5), np.eye(3), np.zeros(3), WIDTH, HEIGHT)


def laser_plane() -> tuple[np.ndarray, float]:
    """The true sheet: unit normal and offset (world = camera frame)."""
    origin = np.array([BASELINE_M, 0.0, 0.0])
    direction = np.array([0.0, 0.0, CROSSING_M]) - origin
    normal = np.cross([0.0, 1.0, 0.0], direction)
    normal /= np.linalg.norm(normal)
    return normal, float(normal @ origin)


def target_planes(rng: np.random.Generator, n_poses: int = 6) -> list[tuple[np.ndarray, float]]:
    """Target planes at distances 0.3-0.6 m, tilted 15-30 degrees about alternating axes."""
    normal_l, offset_l = laser_plane()
    distances = rng.permutation(np.linspace(0.3, 0.6, n_poses))
    planes = []
    for k, z in enumerate(distances):
        angle = np.radians(rng.uniform(15, 30)) * rng.choice([-1, 1])
        axis = [[1.0, 0, 0], [0, 1.0, 0], [1.0, 1.0, 0]][k % 3]
        n_t = Rotation.from_rotvec(angle * np.array(axis) / np.linalg.norm(axis)).apply([0.0, 0.0, 1.0])
        x = (offset_l - normal_l[2] * z) / normal_l[0]  # the sheet at depth z on y = 0
        centre = np.array([x, rng.uniform(-0.02, 0.02), z])
        planes.append((n_t, float(n_t @ centre)))
    return planes


def stripe_line(plane_t) -> np.ndarray:
    """Points ``(200, 3)`` of the line where the sheet meets a target plane (within the board)."""
    normal_l, offset_l = laser_plane()
    n_t, d_t = plane_t
    direction = np.cross(normal_l, n_t)
    direction /= np.linalg.norm(direction)
    A = np.stack([normal_l, n_t, direction])
    origin = np.linalg.solve(A, [offset_l, d_t, 0.0])
    return origin + np.linspace(-HALF_STRIPE_M, HALF_STRIPE_M, 200)[:, None] * direction


def perturbed(plane_t, rng: np.random.Generator, tilt_sigma_rad: float, offset_sigma_m: float):
    """The target plane as a calibration knows it: tilted and shifted by its pose error."""
    n_t, d_t = plane_t
    n_new = Rotation.from_rotvec(rng.normal(0.0, tilt_sigma_rad, 3)).apply(n_t)
    return n_new, d_t + rng.normal(0.0, offset_sigma_m)


def observation(rng: np.random.Generator, n_poses: int = 6, sigma_px: float = 0.2, tilt_sigma_rad: float = 2e-4,
                offset_sigma_m: float = 5e-5, junk_fraction: float = 0.0):
    """Known target planes (with pose errors), noisy stripe pixels and junk pixels of every pose.

    Junk pixels (``junk_fraction`` of each pose's stripe pixels) fall on the target 5-60 mm beside
    the stripe: reflections or texture that a stripe detector may report.

    Returns
    -------
    planes_known : list of (normal (3,), offset)
    pixels : list of ndarray (n_k, 2)
    junk : list of ndarray (m_k, 2)
    """
    cam = camera()
    planes_known, pixels, junk = [], [], []
    for plane_t in target_planes(rng, n_poses):
        line = stripe_line(plane_t)
        pixels.append(cam.project(line) + rng.normal(0.0, sigma_px, (len(line), 2)))
        planes_known.append(perturbed(plane_t, rng, tilt_sigma_rad, offset_sigma_m))
        n_junk = int(round(junk_fraction * len(line)))
        side = np.cross(plane_t[0], line[-1] - line[0])
        side /= np.linalg.norm(side)
        offsets = rng.uniform(0.005, 0.06, (n_junk, 1)) * rng.choice([-1, 1], (n_junk, 1))
        junk.append(cam.project(line[rng.integers(0, len(line), n_junk)] + offsets * side))
    return planes_known, pixels, junk


def normalised_errors(plane, normal_true, offset_true) -> np.ndarray:
    """Errors ``(3,)`` of a fitted plane in its own sigmas: its position at its centroid, and its
    tilt towards each of its in-plane axes."""
    position_m = offset_true - plane.centroid @ normal_true
    tilt_rad = -(plane.axes @ normal_true) * np.sign(plane.normal @ normal_true)
    sigma = np.r_[plane.offset_sigma(plane.centroid[None])[0], plane.tilt_sigma_rad()]
    return np.r_[position_m, tilt_rad] / sigma


def angle_and_offset_error(plane, normal_true, offset_true) -> tuple[float, float]:
    """Angle between the normals (deg) and the offset error (m, with the normals aligned)."""
    sign = np.sign(plane.normal @ normal_true)
    return float(np.degrees(np.arccos(min(1.0, abs(plane.normal @ normal_true))))), sign * plane.offset - offset_true


def true_plane_in_rig_world(session) -> tuple[np.ndarray, float]:
    """A simulated session's true sheet in the world frame of its rig.toml (the target frame at
    the calibration's reference shot, named in rig.toml's metadata): unit normal, offset (m)."""
    import tomllib

    from scanrig.reconstruct.light_plane import load_light_plane

    plane, _ = load_light_plane(session / "truth" / "light_plane.toml")
    world = tomllib.loads((session / "rig.toml").read_text())["metadata"]["world_frame"]
    reference = world.split("'")[1]
    rows = [line.split(",") for name in ("light_plane_poses.csv", "target_poses.csv")
            if (session / "truth" / name).exists() for line in (session / "truth" / name).read_text().splitlines()[1:]]
    values = np.array([row[1:] for row in rows if row[0] == reference][0], float)
    R, t = values[:9].reshape(3, 3), values[9:]
    return R.T @ plane.normal, plane.offset - plane.normal @ t


def rendered_session(root, n_shots: int, seed: int = 3, scene=None):
    """Render ``n_shots`` light-plane shots of the chessboard (laser off and on) into the empty
    folder ``root``: an 800 x 640 camera with f = 600 px, the laser and room of ``scene`` (default:
    the default scene; ~2 s for 8)."""
    from scanrig.geometry import Rig
    from scanrig.sim.calibration_shots import default_target
    from scanrig.sim.library import load_scene
    from scanrig.sim.light_plane_shots import write_light_plane_shots
    from scanrig.targets import save_target

    K = np.array([[600.0, 0, 399.5], [0, 600.0, 319.5], [0, 0, 1]])
    cam = Camera.from_opencv("cam0", K, np.array([-0.1, 0.05, 0, 0, 0]), np.eye(3), np.zeros(3), 800, 640)
    target = default_target("chessboard")
    save_target(target, root / "target.toml")
    write_light_plane_shots(root, scene or load_scene("default"), Rig([cam]), target, n_shots,
                            np.random.default_rng(seed), workers=1)
    return root
