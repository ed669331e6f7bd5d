"""Initial values for the bundle adjustment, with no guess from the user.

1. Intrinsics per camera from planar homographies (Zhang's method, ``cv2.calibrateCamera``) on
   every board seen in every view: a planar target gives one plane per view, the cube two or
   three planes per view, so even a single shot of the cube initialises every camera. When
   these intrinsics fit the camera's views badly (median PnP RMS above
   :data:`ZHANG_ACCEPT_RMS_PX`, as on a fisheye), or Zhang's method
   fails, a central-projection seed refined by a ladder of bundle adjustments is tried
   (:mod:`scanrig.calibration.init_wide`) and the better of the two kept.
2. The pose of the target in every view by PnP (IPPE for one plane, SQPnP otherwise, on the
   corners' lines of sight) refined with Levenberg–Marquardt. A view whose RMS exceeds the gate
   of :func:`~scanrig.calibration.init_wide.view_gate_px` (relative to how well the camera's
   model fits its views) is left out and reported; never every view of a camera.
3. Camera and shot poses by a maximum spanning tree over the bipartite graph cameras–shots
   (edge weight = points in the view), rooted at the first shot: world = target frame there.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np

from scanrig.calibration.init_wide import (
    MAX_VIEW_RMS_PX,
    MIN_POINTS_PER_VIEW,
    LensFitError,
    pnp_bearings,
    view_gate_px,
    wide_angle_intrinsics,
)
from scanrig.calibration.observations import Observations
from scanrig.errors import EstimationError, InputError
from scanrig.geometry.camera import Camera
from scanrig.geometry.distortion import MODEL_COEFFICIENTS
from scanrig.geometry.transform import RigidTransform
from scanrig.geometry.uncertainty import MAD_TO_SIGMA
from scanrig.targets import Target

#: Fewest points of one board in one view for a homography (4 would be exact; 6 gives redundancy).
MIN_POINTS_PER_PLANE = 6
#: Zhang's intrinsics are kept without trying the wide-angle initialisation when the median PnP
#: RMS of the camera's views is at most this (pixels): a lens it models fits to about the corner
#: noise, a fisheye misses by pixels to tens of pixels.
ZHANG_ACCEPT_RMS_PX = 2.0
#: view_pose: corners missing by more than MAX_VIEW_RMS_PX and this many robust sigmas are gross
#: errors (a wrong detection); when they are at most PNP_MAX_GROSS_FRACTION of a view, its pose is
#: solved again without them.
PNP_GROSS_SIGMAS = 5.0
PNP_MAX_GROSS_FRACTION = 0.25
#: Most planes given to ``calibrateCamera`` per camera (evenly spread), to keep it fast.
MAX_PLANES_FOR_INTRINSICS = 40
#: Least ratio of the smaller to the larger principal spread of a board's points in one view for
#: the homography initialisation: below it the points are (nearly) on one line (e.g. one row of a
#: board cut by the image border), which gives no homography and made ``calibrateCamera`` fail.
MIN_PLANE_SPREAD_RATIO = 0.05


@dataclass
class Initialisation:
    """Initial values and what was dropped on the way.

    Attributes
    ----------
    cameras : list of Camera
        Cameras in rig order, ``cam_from_world`` set (world = target frame at :attr:`reference_shot`).
    world_from_target : list of RigidTransform or None
        Per shot; None for shots not connected to the reference shot (excluded from the solve).
    reference_shot : int
        The shot whose target frame is the world frame.
    dropped_views : list of (camera name, shot name, reason)
    """

    cameras: list[Camera]
    world_from_target: list[RigidTransform | None]
    reference_shot: int
    dropped_views: list[tuple[str, str, str]] = field(default_factory=list)


def initialise(obs: Observations, target: Target, models: dict[str, str]) -> Initialisation:
    """Initial intrinsics and poses of every camera and shot (see the module docstring).

    Parameters
    ----------
    obs : Observations
    target : Target
    models : dict
        ``camera name -> model`` (``"opencv4"``, ``"opencv5"``, ``"opencv8"``, ...).

    Raises
    ------
    InputError
        A camera never sees the target, or the cameras do not form one connected graph through
        shared shots.
    EstimationError
        No initialisation fits any view of a camera; the message names the cause (detections that
        match no lens, or corners beyond what the camera model can image).
    """
    counts = obs.view_counts()
    for c, name in enumerate(obs.camera_names):
        if counts[c].sum() == 0:
            raise InputError(f"camera {name!r}: the target was never detected in its calibration images")
    dropped: list[tuple[str, str, str]] = []
    cameras = []
    cam_from_target = {}
    for c, name in enumerate(obs.camera_names):
        camera, poses = _camera_and_views(obs, target, c, models[name])
        cameras.append(camera)
        rms = np.array([rms for _, _, rms in poses.values()])
        gate = view_gate_px(rms)
        for s, (pose, n, rms_s) in poses.items():
            if pose is None or not rms_s <= gate:
                dropped.append((name, obs.shot_names[s], f"PnP failed (rms {rms_s:.3g} px > {gate:.3g} px)"))
            else:
                cam_from_target[(c, s)] = (pose, n)
        for s in np.flatnonzero((counts[c] > 0) & (counts[c] < MIN_POINTS_PER_VIEW)):
            dropped.append((name, obs.shot_names[s], f"{counts[c, s]} points < {MIN_POINTS_PER_VIEW}"))
    cam_from_world, world_from_target, reference = _spanning_tree(cam_from_target, obs)
    cameras = [cam.with_pose(cam_from_world[c]) for c, cam in enumerate(cameras)]
    return Initialisation(cameras, world_from_target, reference, dropped)


def _camera_and_views(obs: Observations, target: Target, c: int, model: str):
    """Initial intrinsics of camera ``c`` and the PnP pose of each of its views.

    Zhang's intrinsics first; when they fail, or their median view RMS exceeds
    :data:`ZHANG_ACCEPT_RMS_PX`, the wide-angle initialisation too, keeping the better fit.

    Returns
    -------
    camera : Camera
    poses : dict
        ``shot -> (cam_from_target or None, n_points, rms_px)`` of every view with at least
        :data:`MIN_POINTS_PER_VIEW` points.

    Raises
    ------
    EstimationError
        Neither initialisation fits any view (the message names the cause).
    """
    camera, poses, median = None, {}, np.inf
    try:
        camera = _intrinsics(obs, target, c, model)
        poses = _view_poses(camera, obs, target, c)
        median = _median_rms(poses)
    except EstimationError:
        pass
    if median <= ZHANG_ACCEPT_RMS_PX:
        return camera, poses
    try:
        wide = wide_angle_intrinsics(obs, target, c, model)
    except LensFitError:
        if median <= MAX_VIEW_RMS_PX:   # Zhang's fit is rough but usable: the gate sorts its views
            return camera, poses
        raise
    wide_poses = _view_poses(wide, obs, target, c)
    if _median_rms(wide_poses) < median:
        camera, poses = wide, wide_poses
    rms = {s: r for s, (_, _, r) in poses.items()}
    s_best = min(rms, key=rms.get) if rms else None
    if s_best is None or not rms[s_best] <= MAX_VIEW_RMS_PX:
        raise EstimationError(
            f"camera {obs.camera_names[c]!r}: no distortion model in the ladder fits the corners of any view "
            + (f"(best PnP RMS {rms[s_best]:.3g} px in view {obs.shot_names[s_best]})" if rms else "(no PnP pose)")
            + f": the lens may exceed what the {model} model can image"
            + ("; use opencv8" if model != "opencv8" else ""))
    return camera, poses


def _view_poses(camera: Camera, obs: Observations, target: Target, c: int) -> dict:
    """``shot -> (cam_from_target or None, n_points, rms_px)`` of camera ``c``'s views with at
    least :data:`MIN_POINTS_PER_VIEW` points."""
    rows = np.flatnonzero(obs.camera == c)
    out = {}
    for s in np.unique(obs.shot[rows]):
        sel = rows[obs.shot[rows] == s]
        if len(sel) >= MIN_POINTS_PER_VIEW:
            pose, rms = view_pose(camera, target, obs.point_id[sel], obs.uv[sel])
            out[int(s)] = (pose, len(sel), rms)
    return out


def _median_rms(poses: dict) -> float:
    """Median RMS (px) of the views that have a pose; inf when none has."""
    rms = [rms for pose, _, rms in poses.values() if pose is not None and np.isfinite(rms)]
    return float(np.median(rms)) if rms else np.inf


def _intrinsics(obs: Observations, target: Target, c: int, model: str) -> Camera:
    """Zhang initialisation of one camera from every board-in-view with enough points.

    Boards with fewer than :data:`MIN_POINTS_PER_PLANE` points in a view, or whose points are
    degenerate for a homography (nearly collinear, see :data:`MIN_PLANE_SPREAD_RATIO`, or no
    finite homography), are skipped here; the bundle adjustment still uses their points.
    """
    import cv2

    name = obs.camera_names[c]
    width, height = obs.image_sizes[name]
    rows = np.flatnonzero(obs.camera == c)
    board_idx = target.board_of(obs.point_id[rows])
    planes_obj, planes_img = [], []
    key = obs.shot[rows] * (len(target.boards) + 1) + board_idx
    for k in np.unique(key[board_idx >= 0]):
        sel = rows[key == k]
        if len(sel) < MIN_POINTS_PER_PLANE:
            continue
        p_board = target.points_on_board(obs.point_id[sel])
        if not _plane_usable(p_board[:, :2], obs.uv[sel]):
            continue
        planes_obj.append(p_board.astype(np.float32))
        planes_img.append(obs.uv[sel].astype(np.float32))
    if not planes_obj:
        raise InputError(f"camera {name!r}: no view shows {MIN_POINTS_PER_PLANE} or more points of one board "
                         "spread over more than a line; take closer or more frontal calibration images")
    if len(planes_obj) > MAX_PLANES_FOR_INTRINSICS:
        pick = np.linspace(0, len(planes_obj) - 1, MAX_PLANES_FOR_INTRINSICS).round().astype(int)
        planes_obj = [planes_obj[i] for i in pick]
        planes_img = [planes_img[i] for i in pick]
    flags = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
    if len(planes_obj) < 3:
        # One or two planes fix the focal length only: keep the principal point at the centre.
        flags |= cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2
    try:
        _, K, dist, _, _ = cv2.calibrateCamera(planes_obj, planes_img, (width, height), None, None, flags=flags)
    except cv2.error as exc:
        raise EstimationError(f"camera {name!r}: homography initialisation failed ({exc.err}); "
                              "add views of the target at several tilts") from None
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise EstimationError(f"camera {name!r}: homography initialisation gave no focal length; "
                              "add views of the target at several tilts")
    n_dist = len(MODEL_COEFFICIENTS[model])
    coeffs = np.zeros(n_dist)
    d = np.ravel(dist)
    coeffs[:min(n_dist, len(d), 5)] = d[:min(n_dist, len(d), 5)]
    params = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], coeffs])
    return Camera(name, model, params, width, height)


def _plane_usable(xy_board: np.ndarray, uv: np.ndarray) -> bool:
    """Whether one board's points in one view give a homography (not nearly collinear, finite H)."""
    import cv2

    xy_board = np.asarray(xy_board, float)
    uv = np.asarray(uv, float)
    if not (np.all(np.isfinite(xy_board)) and np.all(np.isfinite(uv))):
        return False
    for pts in (xy_board, uv):
        sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
        if sv[0] <= 0 or sv[1] < MIN_PLANE_SPREAD_RATIO * sv[0]:
            return False
    try:
        H, _ = cv2.findHomography(xy_board, uv)
    except cv2.error:
        return False
    return H is not None and H.shape == (3, 3) and bool(np.all(np.isfinite(H)))


def view_pose(camera: Camera, target: Target, point_ids: np.ndarray, uv: np.ndarray):
    """Pose ``cam_from_target`` of one view by PnP with the camera's intrinsics, robust to a few
    gross corner errors.

    PnP on the corners' lines of sight (:func:`~scanrig.calibration.init_wide.pnp_bearings`),
    refined with Levenberg–Marquardt on the pixels; when at most :data:`PNP_MAX_GROSS_FRACTION`
    of the corners miss by more than :data:`MAX_VIEW_RMS_PX` and :data:`PNP_GROSS_SIGMAS` robust
    sigmas (or have no image), PnP once more without them.

    Returns
    -------
    pose : RigidTransform or None
        None when PnP fails.
    rms_px : float
        Reprojection RMS of the view's corners at that pose, less the gross errors left out (inf
        on failure).
    """
    p_target, known = target.lookup(point_ids)
    p_target, uv = p_target[known], uv[known]
    if len(p_target) < MIN_POINTS_PER_VIEW:
        return None, np.inf
    xy, _ = camera.unproject(uv)
    bearings = np.column_stack([xy, np.ones(len(xy))]) / np.hypot(np.hypot(xy[:, 0], xy[:, 1]), 1.0)[:, None]
    keep = np.ones(len(uv), bool)
    for _ in range(2):
        pose = _refined_pose(camera, p_target[keep], uv[keep], pnp_bearings(p_target[keep], bearings[keep]))
        if pose is None:
            return None, np.inf
        error_px = np.linalg.norm(camera.with_pose(pose).project(p_target) - uv, axis=1)
        gate = max(MAX_VIEW_RMS_PX, PNP_GROSS_SIGMAS * MAD_TO_SIGMA * float(np.nanmedian(error_px)))
        gross = ~(error_px <= gate)
        if not keep.all() or not gross.any() or gross.mean() > PNP_MAX_GROSS_FRACTION:
            break
        keep = ~gross
    rms = float(np.sqrt(np.mean(error_px[keep] ** 2)))
    return pose, rms if np.isfinite(rms) else np.inf


def _refined_pose(camera: Camera, p_target: np.ndarray, uv: np.ndarray, pose: RigidTransform | None):
    """``pose`` refined by Levenberg–Marquardt on the pixels (``cv2.solvePnPRefineLM``); None on failure."""
    import cv2

    if pose is None:
        return None
    try:
        rvec, tvec = cv2.solvePnPRefineLM(p_target, uv, camera.K, camera.dist, pose.rvec.copy(), pose.t.copy())
    except cv2.error:
        return None
    if not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
        return None
    return RigidTransform.from_rvec_tvec(rvec.ravel(), tvec.ravel())


def _spanning_tree(cam_from_target: dict, obs: Observations):
    """Chain view poses into camera and shot poses along a maximum spanning tree (Prim)."""
    n_cams, n_shots = len(obs.camera_names), len(obs.shot_names)
    shots_seen = sorted({s for _, s in cam_from_target})
    if not shots_seen:
        raise InputError("no view has enough target points for a pose; check the target.toml against the images")
    # Nodes: ("c", i) cameras, ("s", j) shots. Root: the first shot with a view.
    by_node: dict = {}
    for (c, s), (pose, n) in cam_from_target.items():
        by_node.setdefault(("c", c), []).append((n, ("s", s), pose))
        by_node.setdefault(("s", s), []).append((n, ("c", c), pose))
    cam_from_world: dict[int, RigidTransform] = {}
    world_from_target: dict[int, RigidTransform] = {}
    # Root at the first shot that reaches the most cameras (normally shot 0).
    reference = _best_root(by_node, shots_seen)
    world_from_target[reference] = RigidTransform.identity()
    heap: list = []

    def push(node):
        # Equal point counts are common (whole boards in view): ties go to the lower (node,
        # parent) so the tree, and so the initial values, depend on the data only. Every node is
        # pushed once, so (node, parent) is unique and the pose itself is never compared.
        for n, other, pose in by_node.get(node, []):
            heapq.heappush(heap, (-n, other, node, pose))

    push(("s", reference))
    while heap:
        _, node, parent, cam_from_target_pose = heapq.heappop(heap)
        kind, idx = node
        if (kind == "c" and idx in cam_from_world) or (kind == "s" and idx in world_from_target):
            continue
        if kind == "c":   # parent is a shot
            cam_from_world[idx] = cam_from_target_pose @ world_from_target[parent[1]].inverse()
        else:             # parent is a camera
            world_from_target[idx] = cam_from_world[parent[1]].inverse() @ cam_from_target_pose
        push(node)
    missing = [obs.camera_names[c] for c in range(n_cams) if c not in cam_from_world]
    if missing:
        reached = [obs.camera_names[c] for c in sorted(cam_from_world)]
        raise InputError(f"camera graph is disconnected: cameras {missing} share no shot (seen by two cameras) "
                         f"with cameras {reached}; add shots where the target is seen by both groups")
    return ([cam_from_world[c] for c in range(n_cams)],
            [world_from_target.get(s) for s in range(n_shots)], reference)


def _best_root(by_node: dict, shots_seen: list[int]) -> int:
    """The first shot of the largest connected component (so all cameras are reachable if possible)."""
    seen: set = set()
    best, best_size = shots_seen[0], -1
    for s in shots_seen:
        if ("s", s) in seen:
            continue
        stack, comp = [("s", s)], set()
        while stack:
            node = stack.pop()
            if node in comp:
                continue
            comp.add(node)
            stack.extend(other for _, other, _ in by_node.get(node, []))
        seen |= comp
        n_cams = sum(1 for k, _ in comp if k == "c")
        if n_cams > best_size:
            best, best_size = s, n_cams
    return best
