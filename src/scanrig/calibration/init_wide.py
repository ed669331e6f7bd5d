"""Initial intrinsics of lenses Zhang's method cannot start: wide-angle and fisheye lenses.

Zhang's method (:mod:`scanrig.calibration.init`) models a pinhole with mild radial distortion; on
a fisheye its poses miss the corners by tens of pixels in every view. Here, for one camera:

1. **Central-projection seed.** The lens is taken as ``rho = f g(theta)`` about the image centre
   (``rho``: pixel distance from it; ``theta``: angle off the optical axis) for each projection
   ``g`` of :data:`PROJECTIONS` (pinhole ``tan``, stereographic, equidistant, equisolid). For each,
   ``f`` comes from a 1-D search: a candidate ``f`` gives the pose of each of the
   :data:`SEED_VIEWS` views with the most corners by PnP on the lines of sight of its corners, and
   is scored by the median over those views of their reprojection RMS (pixels, through the same
   projection); a geometric grid, then golden-section refinement. The projection and ``f`` with
   the lowest score win.
2. **Conversion to the OpenCV model.** ``fx = fy = f``, the principal point at the image centre,
   and the model's radial coefficients fitted by linear least squares so that the model maps
   ``tan theta`` to ``g(theta)`` over the angles at which the corners were seen.
3. **Ladder.** A bundle adjustment of this camera alone, from the seed's view poses: first
   ``fx fy cx cy`` free with the distortion held, then freeing ``k1 k2``, then ``p1 p2``, then the
   model's other coefficients (:data:`LADDER`).

Views whose seed RMS exceeds :func:`view_gate_px` (relative to the seed's own fit) stay out of the
ladder, never all of them: when no view fits, :class:`~scanrig.errors.EstimationError` names the
cause (detections that do not match the target, or a lens seeing beyond 180 degrees).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.calibration.bundle import bundle_adjust
from scanrig.calibration.observations import Observations
from scanrig.errors import EstimationError, InputError
from scanrig.geometry.camera import Camera
from scanrig.geometry.distortion import MODEL_COEFFICIENTS
from scanrig.geometry.transform import RigidTransform
from scanrig.targets import Target

#: Fewest points in a view for its pose (PnP); views with fewer are dropped and reported.
MIN_POINTS_PER_VIEW = 4
#: Least gate (pixels) on a view's PnP reprojection RMS: a view within it is always kept.
MAX_VIEW_RMS_PX = 10.0
#: The gate is also at least this many times the median view RMS of the current model stage, so
#: that a stage which fits every view only roughly (a seed, a too simple model) keeps its views.
VIEW_GATE_FACTOR = 3.0
#: Central projections ``rho / f = g(theta)`` of the seed: ``(g, inverse of g)``; the inverse is
#: NaN where no angle maps to ``rho / f``, ``g`` NaN where the projection has no image.
PROJECTIONS = {
    "pinhole": (lambda t: np.where(t < np.pi / 2, np.tan(np.minimum(t, np.pi / 2 - 1e-9)), np.nan), np.arctan),
    "stereographic": (lambda t: 2.0 * np.tan(t / 2.0), lambda s: 2.0 * np.arctan(s / 2.0)),
    "equidistant": (lambda t: t, lambda s: s),
    "equisolid": (lambda t: 2.0 * np.sin(t / 2.0),
                  lambda s: np.where(s <= 2.0, 2.0 * np.arcsin(np.minimum(s, 2.0) / 2.0), np.nan)),
}
#: Focal lengths searched, as multiples of the image's half diagonal (a 10x long lens to a
#: fisheye whose image circle is ten times smaller than the sensor), and grid points.
FOCAL_RANGE = (0.1, 10.0)
FOCAL_GRID = 25
#: Golden-section steps refining the best grid focal length (bracket shrinks 0.618 per step).
FOCAL_REFINE_STEPS = 10
#: Views (those with the most points) used by the focal-length search.
SEED_VIEWS = 12
#: Lines of sight further than this off a view's mean line of sight are left out of its PnP
#: (their normalised coordinates ``tan theta`` grow without bound); they still count in the RMS.
PNP_MAX_ANGLE_RAD = np.radians(80.0)
#: OpenCV models project ``tan theta``: no corner at or beyond 90 degrees off axis has an image;
#: the conversion is fitted up to the largest observed angle, at most this.
FIT_MAX_ANGLE_RAD = np.radians(88.0)
#: Cumulative parameter groups freed by the ladder (those the model has).
LADDER = (("fx", "fy", "cx", "cy"), ("k1", "k2"), ("p1", "p2"), ("k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4"))
#: Levenberg–Marquardt iterations per ladder stage.
LADDER_ITERATIONS = 50


class LensFitError(EstimationError):
    """No seed projection fits any view of a camera (the message names the best view)."""


def view_gate_px(rms_px: np.ndarray) -> float:
    """Largest PnP RMS (pixels) of a view kept at this model stage: the larger of
    :data:`MAX_VIEW_RMS_PX` and :data:`VIEW_GATE_FACTOR` times the median finite view RMS."""
    finite = np.asarray(rms_px, float)[np.isfinite(rms_px)]
    return max(MAX_VIEW_RMS_PX, VIEW_GATE_FACTOR * float(np.median(finite))) if len(finite) else MAX_VIEW_RMS_PX


def coplanar(points: np.ndarray) -> bool:
    """Whether points (N, 3) lie on one plane (to 1 nm)."""
    centred = points - points.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    return bool(np.ptp(centred @ normal) < 1e-9)


def pnp_bearings(p_target: np.ndarray, bearings: np.ndarray) -> RigidTransform | None:
    """``cam_from_target`` from target points (N, 3) and the unit lines of sight (N, 3, camera
    frame) on which they are seen; None when PnP fails.

    PnP (IPPE for one plane, SQPnP otherwise) runs in a virtual pinhole camera turned towards the
    mean line of sight, so that views far off the axis of a wide-angle lens are as well
    conditioned as central ones; lines of sight more than :data:`PNP_MAX_ANGLE_RAD` off that
    virtual axis are left out.
    """
    Rt = _pnp_bearings(p_target, bearings)
    return None if Rt is None else RigidTransform(*Rt)


def _pnp_bearings(p_target: np.ndarray, bearings: np.ndarray):
    """:func:`pnp_bearings` as ``(R (3, 3), t (3,))`` or None (the search's hot path)."""
    import cv2

    ok = np.all(np.isfinite(bearings), axis=1)
    p_target, bearings = p_target[ok], bearings[ok]
    if len(p_target) < MIN_POINTS_PER_VIEW:
        return None
    axis = bearings.mean(axis=0)
    norm = np.sqrt(axis @ axis)
    if not norm > 0:
        return None
    virtual_from_cam = _rotation_to_z(axis / norm)
    b = bearings @ virtual_from_cam.T
    near = b[:, 2] > np.cos(PNP_MAX_ANGLE_RAD)
    if np.count_nonzero(near) < MIN_POINTS_PER_VIEW:
        return None
    xy = b[near, :2] / b[near, 2:]
    method = cv2.SOLVEPNP_IPPE if coplanar(p_target[near]) else cv2.SOLVEPNP_SQPNP
    try:
        ok, rvec, tvec = cv2.solvePnP(p_target[near], xy, np.eye(3), None, flags=method)
    except cv2.error:   # degenerate point sets (e.g. all on one line)
        return None
    if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
        return None
    R_virtual = cv2.Rodrigues(rvec)[0]
    return virtual_from_cam.T @ R_virtual, virtual_from_cam.T @ tvec.ravel()


def _rotation_to_z(axis: np.ndarray) -> np.ndarray:
    """A rotation matrix (3, 3) taking the unit vector ``axis`` to ``(0, 0, 1)``."""
    # x: the unit vector along helper x axis, with helper = e_x or e_y (whichever is less parallel).
    ax, ay, az = axis
    x = np.array([0.0, az, -ay]) if abs(ax) < 0.9 else np.array([-az, 0.0, ax])
    x /= np.sqrt(x @ x)
    y = np.array([ay * x[2] - az * x[1], az * x[0] - ax * x[2], ax * x[1] - ay * x[0]])
    return np.stack([x, y, axis])


@dataclass(frozen=True)
class CentralLens:
    """``rho = f g(theta)`` about the pixel ``c_px`` (a seed, see the module docstring)."""

    projection: str
    f_px: float
    c_px: tuple[float, float]

    def angles(self, uv: np.ndarray):
        """Angle off the axis (rad) and azimuth of pixels (N, 2); NaN angle where none maps there."""
        d = uv - np.asarray(self.c_px)
        theta = PROJECTIONS[self.projection][1](np.hypot(d[:, 0], d[:, 1]) / self.f_px)
        return theta, np.arctan2(d[:, 1], d[:, 0])

    def bearings(self, uv: np.ndarray) -> np.ndarray:
        """Unit lines of sight (N, 3, camera frame) of pixels (N, 2); NaN where none maps there."""
        theta, phi = self.angles(uv)
        return np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])

    def project_cam(self, p_cam: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) of camera-frame points (N, 3); NaN where the projection has no image."""
        theta = np.arctan2(np.hypot(p_cam[:, 0], p_cam[:, 1]), p_cam[:, 2])
        rho = self.f_px * PROJECTIONS[self.projection][0](theta)
        phi = np.arctan2(p_cam[:, 1], p_cam[:, 0])
        return np.asarray(self.c_px) + rho[:, None] * np.column_stack([np.cos(phi), np.sin(phi)])


@dataclass
class _View:
    shot: int
    p_target: np.ndarray
    uv: np.ndarray


def _view_fit(lens: CentralLens, view: _View):
    """``((R, t) of cam_from_target, or None; RMS px, inf on failure)`` of one view through a
    central lens."""
    Rt = _pnp_bearings(view.p_target, lens.bearings(view.uv))
    if Rt is None:
        return None, np.inf
    with np.errstate(invalid="ignore", over="ignore"):   # a candidate far off may image points at infinity
        err2 = np.sum((lens.project_cam(view.p_target @ Rt[0].T + Rt[1]) - view.uv) ** 2, axis=1)
        rms = float(np.sqrt(np.mean(err2)))
    return Rt, rms if np.isfinite(rms) else np.inf


def _score(lens: CentralLens, views: list[_View]) -> float:
    """Median view RMS (px) through ``lens``."""
    return float(np.median([_view_fit(lens, v)[1] for v in views]))


def fit_central_lens(views: list[_View], width: int, height: int) -> tuple[CentralLens | None, float]:
    """Best seed lens over :data:`PROJECTIONS` and focal lengths, and its score (median view RMS,
    px); ``(None, inf)`` when no candidate gives a pose to half of the views."""
    c_px = ((width - 1) / 2.0, (height - 1) / 2.0)
    half_diagonal = 0.5 * np.hypot(width, height)
    log_f = np.log(half_diagonal * np.geomspace(*FOCAL_RANGE, FOCAL_GRID))
    best, best_score = None, np.inf
    for projection in PROJECTIONS:
        def score(lf, projection=projection):
            return _score(CentralLens(projection, float(np.exp(lf)), c_px), views)

        scores = np.array([score(lf) for lf in log_f])
        i = int(np.argmin(scores))
        lo, hi = log_f[max(i - 1, 0)], log_f[min(i + 1, len(log_f) - 1)]
        lf, s = _golden_section(score, lo, hi, log_f[i], scores[i])
        if s < best_score:
            best, best_score = CentralLens(projection, float(np.exp(lf)), c_px), s
    return best, best_score


def _golden_section(fun, lo: float, hi: float, x_best: float, f_best: float) -> tuple[float, float]:
    """Minimum of ``fun`` on ``[lo, hi]`` by :data:`FOCAL_REFINE_STEPS` golden-section steps
    (or the given best point if none is lower)."""
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    x1, x2 = b - ratio * (b - a), a + ratio * (b - a)
    f1, f2 = fun(x1), fun(x2)
    for _ in range(FOCAL_REFINE_STEPS):
        if f1 <= f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - ratio * (b - a)
            f1 = fun(x1)
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + ratio * (b - a)
            f2 = fun(x2)
    for x, f in ((x1, f1), (x2, f2)):
        if f < f_best:
            x_best, f_best = x, f
    return x_best, f_best


def opencv_coefficients(projection: str, model: str, max_angle_rad: float) -> np.ndarray:
    """Distortion coefficients of ``model`` (OpenCV order) that map ``tan theta`` to ``g(theta)``
    of ``projection`` for ``theta`` up to ``max_angle_rad``: least squares on the radial terms
    (``k1 k2 k3`` over ``k4 k5 k6``, those the model has), the others zero."""
    names = MODEL_COEFFICIENTS[model]
    theta = np.linspace(1e-3, max_angle_rad, 200)
    r, g = np.tan(theta), PROJECTIONS[projection][0](theta)
    r2 = r * r
    num = [n for n in ("k1", "k2", "k3") if n in names]
    den = [n for n in ("k4", "k5", "k6") if n in names]
    power = {"k1": 1, "k2": 2, "k3": 3, "k4": 1, "k5": 2, "k6": 3}
    # r (1 + sum a_j r^2j) = g (1 + sum b_j r^2j): linear in a, b; reweighted so that the error
    # is that of r_d itself (divided by the denominator).
    A = np.column_stack([r * r2 ** power[n] for n in num] + [-g * r2 ** power[n] for n in den])
    b = g - r
    coeffs = np.zeros(A.shape[1])
    if A.shape[1]:
        w = np.ones_like(r)
        for _ in range(5):
            scale = np.linalg.norm(A * w[:, None], axis=0)
            coeffs = np.linalg.lstsq(A * w[:, None] / scale, b * w, rcond=None)[0] / scale
            denominator = np.ones_like(r) + sum(coeffs[len(num) + j] * r2 ** power[n] for j, n in enumerate(den))
            w = 1.0 / np.abs(denominator)
    out = np.zeros(len(names))
    for value, name in zip(coeffs, num + den):
        out[names.index(name)] = value
    return out


def wide_angle_intrinsics(obs: Observations, target: Target, c: int, model: str) -> Camera:
    """Intrinsics of camera ``c`` by the seed, conversion and ladder of the module docstring.

    Returns
    -------
    Camera
        Of ``model``, at the identity pose.

    Raises
    ------
    LensFitError
        No seed projection fits any view (the message names the best view and its RMS).
    EstimationError
        The corners lie :data:`FIT_MAX_ANGLE_RAD` or more off the axis, which no OpenCV model
        can image.
    """
    name = obs.camera_names[c]
    width, height = obs.image_sizes[name]
    views = _views(obs, target, c)
    if not views:
        raise InputError(f"camera {name!r}: no view has {MIN_POINTS_PER_VIEW} or more target points")
    by_size = sorted(range(len(views)), key=lambda i: (-len(views[i].uv), i))
    seed_views = [views[i] for i in sorted(by_size[:SEED_VIEWS])]
    lens, _ = fit_central_lens(seed_views, width, height)
    fits = [_view_fit(lens, v) if lens is not None else (None, np.inf) for v in views]
    rms = np.array([f[1] for f in fits])
    best = int(np.argmin(rms))
    if lens is None or not rms[best] <= MAX_VIEW_RMS_PX:
        raise LensFitError(
            f"camera {name!r}: no lens model fits the corners of any view (best PnP RMS {rms[best]:.3g} px in "
            f"view {obs.shot_names[views[best].shot]}; Zhang's pinhole with k1 k2 and the "
            f"{', '.join(PROJECTIONS)} projections tried): check that target.toml matches the board (rows, "
            "columns, square size, corner order) and that the detections are of that board")
    theta = np.concatenate([lens.angles(v.uv)[0] for v in views])
    beyond = ~(theta < FIT_MAX_ANGLE_RAD)
    if np.any(beyond):
        n_views = sum(bool(np.any(~(lens.angles(v.uv)[0] < FIT_MAX_ANGLE_RAD))) for v in views)
        raise EstimationError(
            f"camera {name!r}: {int(beyond.sum())} corners in {n_views} views lie {np.degrees(FIT_MAX_ANGLE_RAD):.0f} "
            f"degrees or more off the optical axis (up to {np.degrees(np.nanmax(theta)):.0f} degrees by the "
            f"{lens.projection} fit, f = {lens.f_px:.0f} px): the lens sees beyond what the {model} model can "
            "image (under 180 degrees across); leave the corners near the rim of the image circle out "
            "(calibrate --corners with a filtered corners.csv)")
    coeffs = opencv_coefficients(lens.projection, model, float(np.nanmax(theta)))
    camera = Camera(name, model, np.concatenate([[lens.f_px, lens.f_px], lens.c_px, coeffs]), width, height)
    keep = [i for i in range(len(views)) if rms[i] <= view_gate_px(rms)]
    return _ladder(camera, obs, target, c, [views[i] for i in keep], [RigidTransform(*fits[i][0]) for i in keep])


def _views(obs: Observations, target: Target, c: int) -> list[_View]:
    """Camera ``c``'s views with at least :data:`MIN_POINTS_PER_VIEW` known target points."""
    rows = np.flatnonzero(obs.camera == c)
    p_target, known = target.lookup(obs.point_id[rows])
    views = []
    for s in np.unique(obs.shot[rows]):
        sel = (obs.shot[rows] == s) & known
        if np.count_nonzero(sel) >= MIN_POINTS_PER_VIEW:
            views.append(_View(int(s), p_target[sel], obs.uv[rows[sel]]))
    return views


def _ladder(camera: Camera, obs: Observations, target: Target, c: int, views: list[_View],
            cam_from_target: list[RigidTransform]) -> Camera:
    """Single-camera bundle adjustments freeing :data:`LADDER` step by step; returns the camera
    of the last stage that solved (identity pose)."""
    shots = np.array([v.shot for v in views])
    rows = (obs.camera == c) & np.isin(obs.shot, shots)
    sub = Observations(np.zeros(np.count_nonzero(rows), np.int64), obs.shot[rows], obs.point_id[rows], obs.uv[rows],
                       obs.weight[rows], (camera.name,), obs.shot_names, {camera.name: obs.image_sizes[camera.name]})
    reference = int(shots[0])
    camera = camera.with_pose(cam_from_target[0])
    world_from_target: list = [None] * len(obs.shot_names)
    for v, pose in zip(views, cam_from_target):
        world_from_target[v.shot] = camera.cam_from_world.inverse() @ pose
    free: set[str] = set()
    for group in LADDER:
        new = set(group) & set(camera.param_names) - free
        if not new:
            continue
        free |= new
        fixed = tuple(n for n in camera.param_names if n not in free)
        try:
            res = bundle_adjust(sub, target, [camera], world_from_target, reference, {camera.name: fixed},
                                robust=False, max_iterations=LADDER_ITERATIONS)
        except (EstimationError, InputError):
            break
        camera, world_from_target = res.state.cameras[0], res.state.world_from_target
    return camera.with_pose(RigidTransform.identity())
