"""Synthetic calibration observations with known truth, for tests and benchmarks.

Cameras on a ring look at the origin; the target is posed near the origin
(:func:`random_target_poses`) or, as a calibrating user does, moved over the cameras' whole
fields of view and depth range (:func:`covering_target_poses`); every target point that is in
front of a camera, inside its image and seen from the printed side at less than
:data:`MAX_VIEW_ANGLE_DEG` from the board normal is observed with Gaussian pixel noise.
Optionally (``min_square_px``) a point is observed only where its board's squares image at
least that many pixels across along their foreshortened direction, as real detectors need:
a ChArUco face of 25 mm squares rendered at 1.25 m (28 px squares; blur 0.8 px, noise 2 DN)
gives 169 of 169 corners face-on, 127 at 45 deg (20 px foreshortened), 28 at 60 deg (14 px)
and none at 70 deg (10 px); at 0.9 m, 138 at 60 deg (19 px) and 61 at 70 deg (13 px); at
0.6 m, 130 at 70 deg (20 px).

Optionally (``flex_m``) every board is bent by the two flex terms of
:func:`scanrig.targets.target.flex_shape`, as a foam or card board bends.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.calibration.observations import Observations
from scanrig.geometry.camera import Camera
from scanrig.geometry.transform import RigidTransform
from scanrig.targets import Target

#: Steepest view of a board (angle between the line of sight and the board normal) still detected.
MAX_VIEW_ANGLE_DEG = 70.0
#: Foreshortened square size (px) at which about half of a ChArUco face's corners are still
#: found in the renders quoted in the module docstring (14 px: 17-36 %, 19-20 px: 75-82 %).
DETECTABLE_SQUARE_PX = 16.0


@dataclass
class SyntheticCalibration:
    """Truth and observations of a simulated calibration."""

    cameras: list[Camera]
    world_from_target: list[RigidTransform]
    obs: Observations
    sigma_px: float


def look_at(center_world: np.ndarray, target_world: np.ndarray, up=(0.0, 0.0, 1.0)) -> RigidTransform:
    """``cam_from_world`` of a camera at ``center_world`` looking at ``target_world`` (y down)."""
    z = np.asarray(target_world, float) - np.asarray(center_world, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])          # rows: camera axes in world coordinates
    return RigidTransform(R, -R @ np.asarray(center_world, float))


def ring_cameras(n_cameras: int, distance_m: float = 0.8, elevation_deg: float = 30.0, spread_deg: float = 30.0,
                 size=(1280, 1024), focal_px: float = 1400.0, model: str = "opencv5",
                 rng: np.random.Generator | None = None, center_m=(0.0, 0.0, 0.0)) -> list[Camera]:
    """Cameras on an arc around the origin, ``spread_deg`` apart, with mild distortion.

    The arc is centred on azimuth 45° (between the target's +x and +y axes) at ``elevation_deg``
    above the xy plane around ``center_m``, all looking at ``center_m``: a cube at the origin
    shows each camera three faces. A planar board (printed side facing -z) is seen from a
    negative elevation. ``rng`` perturbs the intrinsics (so cameras differ); None gives
    identical intrinsics.
    """
    w, h = size
    cams = []
    el = np.deg2rad(elevation_deg)
    for k in range(n_cameras):
        az = np.deg2rad(45.0 + spread_deg * (k - (n_cameras - 1) / 2))
        centre = np.asarray(center_m, float) + distance_m * np.array(
            [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        jitter = rng.normal(size=4) if rng is not None else np.zeros(4)
        base = [focal_px * (1 + 0.02 * jitter[0]), focal_px * (1 + 0.02 * jitter[0]) * 1.001,
                w / 2 + 8 * jitter[1], h / 2 + 8 * jitter[2]]
        dist = {"opencv4": [-0.12, 0.08, 2e-4, -1e-4], "opencv5": [-0.12, 0.08, 2e-4, -1e-4, -0.02],
                "opencv8": [-0.12, 0.08, 2e-4, -1e-4, -0.02, 0.01, 0.005, 0.002]}[model]
        cams.append(Camera(f"cam{k}", model, np.array(base + dist), w, h, look_at(centre, np.asarray(center_m, float))))
    return cams


def random_target_poses(n_shots: int, rng: np.random.Generator, max_tilt_deg: float = 35.0,
                        max_shift_m: float = 0.1) -> list[RigidTransform]:
    """Target poses near the origin: shot 0 is the identity (the world frame), others random."""
    from scipy.spatial.transform import Rotation

    poses = [RigidTransform.identity()]
    for _ in range(n_shots - 1):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = np.deg2rad(rng.uniform(0.3, 1.0) * max_tilt_deg)
        poses.append(RigidTransform(Rotation.from_rotvec(axis * angle).as_matrix(),
                                    rng.uniform(-max_shift_m, max_shift_m, size=3)))
    return poses


def covering_target_poses(cameras: list[Camera], target: Target, n_shots: int, rng: np.random.Generator,
                          image_margin: float = 0.1, depth_m: float = 0.25, min_cameras: int = 2,
                          min_points: int = 12, max_tries: int = 200,
                          min_square_px: float | None = None) -> list[RigidTransform]:
    """Target poses spread over the cameras' fields of view, as a calibrating user takes them.

    Shot 0 is the identity (the world frame). For every other shot, the cameras take turns: a
    pixel is drawn uniformly over the camera's image less ``image_margin`` (fraction of width and
    height) on each side, the target centre is put on that pixel's ray at a depth (camera z)
    uniform within ``± depth_m`` of the depth of the cameras' aim point (the world origin), and
    the target gets a uniformly random orientation. Since the target extends around its centre,
    shots drawn near a border see it cut by the image edge, so every camera sees target points
    up to its image corners. A pose is kept when at least ``min_cameras`` cameras each see at
    least ``min_points`` points (with the visibility rules of :func:`observe`); otherwise it is
    drawn again (at most ``max_tries`` times per shot). ``min_square_px`` as in :func:`observe`.

    Raises
    ------
    ValueError
        No pose seen by ``min_cameras`` cameras within ``max_tries`` draws.
    """
    from scipy.spatial.transform import Rotation

    poses = [RigidTransform.identity()]
    # Target centre (target frame) from its points, so the drawn pixel is the target's middle.
    centre_target = 0.5 * (target.points_target.min(axis=0) + target.points_target.max(axis=0))
    for s in range(1, n_shots):
        cam = cameras[(s - 1) % len(cameras)]
        aim_depth = cam.cam_from_world.apply(np.zeros((1, 3)))[0, 2]
        for _ in range(max_tries):
            w, h = cam.width, cam.height
            q = rng.uniform([image_margin * w, image_margin * h], [(1 - image_margin) * w, (1 - image_margin) * h])
            xy, ok = cam.unproject(q[None, :])
            if not ok[0]:
                continue
            depth = aim_depth + rng.uniform(-depth_m, depth_m)
            centre_world = cam.cam_from_world.inverse().apply((np.append(xy[0], 1.0) * depth)[None, :])[0]
            R = Rotation.random(random_state=rng).as_matrix()
            pose = RigidTransform(R, centre_world - R @ centre_target)
            if sum(np.count_nonzero(_visible(c, target, pose, min_square_px)) >= min_points
                   for c in cameras) >= min_cameras:
                poses.append(pose)
                break
        else:
            raise ValueError(f"no target pose seen by {min_cameras} cameras in {max_tries} draws (shot {s})")
    return poses


def _visible(cam: Camera, target: Target, pose: RigidTransform, min_square_px: float | None = None) -> np.ndarray:
    """Which target points ``cam`` sees with the target at ``pose`` (world_from_target)."""
    return _project_visible(cam, target, pose, min_square_px)[0]


def _board_pitch_m(board) -> float:
    """Square side (chessboard, ChArUco) or circle spacing of a board, metres."""
    return float(getattr(board, "square_m", None) or board.spacing_m)


def _project_visible(cam: Camera, target: Target, pose: RigidTransform, min_square_px: float | None = None,
                     flex_m=None):
    """Visibility mask (see the module docstring) and pixels of every target point in ``cam``,
    the boards bent by ``flex_m`` (``(c_x, c_y)``, metres; None: flat)."""
    normals_target = np.concatenate([np.tile(b.target_from_board.R[:, 2], (len(b.point_ids), 1))
                                     for b in target.boards])
    cos_max = np.cos(np.deg2rad(MAX_VIEW_ANGLE_DEG))
    p_target = target.points_target
    if flex_m is not None:
        p_target = p_target + target.flex_directions(target.point_ids) @ np.asarray(flex_m, dtype=np.float64)
    p_world = pose.apply(p_target)
    inward_world = normals_target @ pose.R.T          # board z (into the board), world frame
    q = cam.project(p_world)
    sight = p_world - cam.center_world
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    cos_view = np.sum(sight * inward_world, axis=1)
    facing = cos_view > cos_max
    if min_square_px is not None:
        # Foreshortened size of the point's squares: pitch * f / range * cos(view angle).
        pitch = np.concatenate([np.full(len(b.point_ids), _board_pitch_m(b)) for b in target.boards])
        ranges = np.linalg.norm(p_world - cam.center_world, axis=1)
        facing &= pitch * min(cam.params[0], cam.params[1]) / ranges * cos_view >= min_square_px
    inside = np.all(np.isfinite(q), axis=1) & (q[:, 0] > 0) & (q[:, 1] > 0) \
        & (q[:, 0] < cam.width - 1) & (q[:, 1] < cam.height - 1)
    return facing & inside, q


def observe(cameras: list[Camera], target: Target, world_from_target: list[RigidTransform],
            sigma_px: float, rng: np.random.Generator, min_square_px: float | None = None,
            flex_m=None) -> Observations:
    """Noisy observations of every visible target point (see the module docstring).

    ``min_square_px``: observe a point only where its board's squares (circle spacing) image at
    least this many pixels along their foreshortened direction (None: no size limit);
    :data:`DETECTABLE_SQUARE_PX` matches the rendered ChArUco detections. ``flex_m``: (2,)
    flex terms ``(c_x, c_y)`` (metres) bending every board (None: flat boards).
    """
    parts = []
    shot_names = [f"{s:03d}" for s in range(len(world_from_target))]
    for s, pose in enumerate(world_from_target):
        for cam in cameras:
            keep, q = _project_visible(cam, target, pose, min_square_px, flex_m)
            if np.count_nonzero(keep) == 0:
                continue
            noisy = q[keep] + rng.normal(scale=sigma_px, size=(np.count_nonzero(keep), 2))
            parts.append((cam.name, shot_names[s], target.point_ids[keep], noisy, np.ones(np.count_nonzero(keep))))
    sizes = {cam.name: (cam.width, cam.height) for cam in cameras}
    return Observations.concatenate(parts, [c.name for c in cameras], shot_names, sizes)


def simulate(cameras: list[Camera], target: Target, n_shots: int, sigma_px: float,
             rng: np.random.Generator, cover: bool = False, min_square_px: float | None = None,
             flex_m=None, **pose_options) -> SyntheticCalibration:
    """Random target poses (shot 0 = world) and noisy observations of them.

    ``cover=False``: poses near the origin (:func:`random_target_poses`); ``cover=True``: poses
    spread over the cameras' fields of view and depth (:func:`covering_target_poses`, which
    then also gets ``min_square_px``). ``pose_options`` go to the chosen function;
    ``min_square_px`` and ``flex_m`` (bent boards) to :func:`observe`.
    """
    if cover:
        poses = covering_target_poses(cameras, target, n_shots, rng, min_square_px=min_square_px, **pose_options)
    else:
        poses = random_target_poses(n_shots, rng, **pose_options)
    obs = observe(cameras, target, poses, sigma_px, rng, min_square_px, flex_m)
    return SyntheticCalibration(cameras, poses, obs, sigma_px)


#: Sub-samples per axis with which :func:`render_board` re-renders pixels cut by an edge.
EDGE_SUPERSAMPLE = 16


def render_board(board, camera: Camera, cam_from_board: RigidTransform, blur_px: float, noise_dn: float,
                 rng: np.random.Generator, supersample: int = 4, black_dn: float = 30.0,
                 white_dn: float = 220.0) -> np.ndarray:
    """Render a board as the camera sees it: exact geometry, area sampling, blur, noise.

    Each pixel averages ``supersample²`` rays intersected with the board plane (true lens
    model, so the corners' truth is ``camera.project_cam(cam_from_board.apply(points_board))``);
    pixels whose rays do not all agree (an edge crosses them) are re-rendered with
    :data:`EDGE_SUPERSAMPLE`² rays. (With 4 x 4 rays alone, an edge along the pixel grid is
    placed on a 1/4-px lattice: up to 0.125 px of systematic error per edge, ~0.1 px RMS at a
    fronto-parallel corner, which a corner benchmark would then charge to the detector.) Then a
    Gaussian blur of ``blur_px`` (sigma) and Gaussian noise of ``noise_dn`` are applied and the
    result is rounded to 8 bits. Off the board the paper is white.

    Returns
    -------
    ndarray of shape (H, W), uint8
    """
    import cv2

    w, h = camera.width, camera.height
    cam0 = camera.with_pose(RigidTransform.identity())

    def reflectance(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        xy, ok = cam0.unproject(np.column_stack([u, v]))
        rays = np.column_stack([xy, np.ones(len(xy))])
        # Plane z_board = 0 in camera frame: normal R[:, 2], passing through t.
        normal, origin = cam_from_board.R[:, 2], cam_from_board.t
        depth = (origin @ normal) / (rays @ normal)
        hit_board = (rays * depth[:, None] - origin) @ cam_from_board.R
        refl = np.ones(len(rays))
        good = ok & (depth > 0)
        refl[good] = board.reflectance(hit_board[good, :2])
        return refl

    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    u = (np.arange(w)[:, None] + offsets[None, :]).ravel()
    v = (np.arange(h)[:, None] + offsets[None, :]).ravel()
    uu, vv = np.meshgrid(u, v)
    samples = reflectance(uu.ravel(), vv.ravel()).reshape(h, supersample, w, supersample)
    img = samples.mean(axis=(1, 3))
    edge_v, edge_u = np.nonzero(samples.max(axis=(1, 3)) > samples.min(axis=(1, 3)))
    fine = (np.arange(EDGE_SUPERSAMPLE) + 0.5) / EDGE_SUPERSAMPLE - 0.5
    fu, fv = (a.ravel() for a in np.meshgrid(fine, fine))
    chunk = 4096
    for k in range(0, len(edge_u), chunk):
        eu, ev = edge_u[k:k + chunk], edge_v[k:k + chunk]
        r = reflectance((eu[:, None] + fu[None, :]).ravel(), (ev[:, None] + fv[None, :]).ravel())
        img[ev, eu] = r.reshape(len(eu), -1).mean(axis=1)
    img = black_dn + (white_dn - black_dn) * img
    if blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_px)
    img = img + rng.normal(scale=noise_dn, size=img.shape) if noise_dn > 0 else img
    return np.clip(np.round(img), 0, 255).astype(np.uint8)
