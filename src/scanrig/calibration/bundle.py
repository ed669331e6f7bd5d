"""Joint sparse bundle adjustment of every camera's intrinsics and pose and every target pose.

Unknowns: per camera its free intrinsic parameters and ``cam_from_world`` (rvec, tvec); per
shot ``world_from_target`` (rvec, tvec), except the reference shot whose target frame *is* the
world (the gauge). The target geometry is known, except that a target declared flexible
(``flex = true``, a planar board) adds its two flex terms ``c = (c_x, c_y)`` (metres,
:func:`scanrig.targets.target.flex_shape`), last in the parameter vector and shared by every
shot: the point then sits at ``p + D_p c``, ``D_p`` its (3, 2)
:meth:`~scanrig.targets.Target.flex_directions`. Residual of observation i (camera c, shot s,
target point p, pixel q, weight w)::

    r_i = sqrt(w_i * irls_i) * (project_c(world_from_target_s · (p + D_p c)) - q)       (pixels)

The Jacobian is assembled from the camera model's analytic derivatives
(:meth:`Camera.project_with_jacobians`) into a scipy.sparse matrix.

Robustness: iteratively reweighted least squares with Huber weights on each observation's
residual norm (scale from the median residual), then iterated outlier rejection at
:data:`OUTLIER_SIGMAS` robust sigmas; every rejected observation is listed in the result.
The final solve uses plain least squares on the inliers, so the covariance is the textbook one.

Intrinsics known from elsewhere (a separate calibration of each camera) enter either held fixed
(``fixed_params``) or as Gaussian priors (``priors``): one extra residual row per prior parameter,
``sigma_px * (x_k - mean_k) / std_k``, with ``sigma_px`` the residual scale of the pixels, so that
``sigma_px² (JᵀJ)⁻¹`` holds the prior's own variance ``std_k²``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse

from scanrig.calibration.lm import COST_RTOL, levenberg_marquardt
from scanrig.calibration.observations import Observations
from scanrig.errors import EstimationError, InputError
from scanrig.geometry.camera import Camera
from scanrig.geometry.transform import RigidTransform, skew
from scanrig.targets import Target

#: Huber threshold on the normalised residual norm (robust sigmas). 2.0 keeps ~86 % of a clean
#: 2-D Gaussian sample at full weight (Rayleigh CDF at 2) while capping gross errors.
HUBER_SIGMAS = 2.0
#: Rejection threshold (robust sigmas): a clean 2-D Gaussian residual norm exceeds 5 sigma with
#: probability exp(-12.5) = 3.7e-6, so clean data loses essentially nothing.
OUTLIER_SIGMAS = 5.0
#: Median of a 2-D standard normal vector's norm (Rayleigh): sqrt(2 ln 2).
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))
#: Rounds of reject-and-resolve before giving up on further outliers.
MAX_REJECTION_ROUNDS = 4
#: IRLS reweighting rounds per rejection round.
IRLS_ROUNDS = 3
#: Relative cost change at which the intermediate (reweighting) solves stop; the weights change
#: more than that between rounds anyway. The final solve runs to lm.COST_RTOL.
IRLS_COST_RTOL = 1e-6
#: Largest change of any IRLS weight for the weights to count as settled.
IRLS_WEIGHT_ATOL = 0.02


@dataclass
class Layout:
    """Where each unknown sits in the parameter vector.

    Attributes
    ----------
    intrinsics : list of ndarray of int
        Per camera, the positions in ``x`` of its free intrinsic parameters (-1 = held fixed).
    camera_pose : list of slice or None
        Per camera, its 6 pose parameters (rvec, tvec of ``cam_from_world``); None = fixed.
    shot_pose : list of slice or None
        Per shot, its 6 pose parameters (rvec, tvec of ``world_from_target``); None = fixed
        (the reference shot) or not solved (see ``shot_active``).
    shot_active : ndarray of bool
    size : int
    flex : slice or None
        The target's two flex terms (last in ``x``); None for a rigid target.
    """

    intrinsics: list[np.ndarray]
    camera_pose: list[slice | None]
    shot_pose: list[slice | None]
    shot_active: np.ndarray
    size: int
    flex: slice | None = None

    @classmethod
    def build(cls, cameras: list[Camera], shot_active: np.ndarray, reference_shot: int,
              fixed_params: dict[str, tuple[str, ...]], fix_poses: tuple[str, ...] = (),
              flex: bool = False) -> Layout:
        n = 0
        intrinsics = []
        for cam in cameras:
            fixed = set(fixed_params.get(cam.name, ()))
            index = np.full(len(cam.params), -1)
            for k, pname in enumerate(cam.param_names):
                if pname not in fixed:
                    index[k] = n
                    n += 1
            intrinsics.append(index)
        camera_pose = []
        for cam in cameras:
            if cam.name in fix_poses:
                camera_pose.append(None)
            else:
                camera_pose.append(slice(n, n + 6))
                n += 6
        shot_pose = []
        for s, active in enumerate(shot_active):
            if active and s != reference_shot:
                shot_pose.append(slice(n, n + 6))
                n += 6
            else:
                shot_pose.append(None)
        flex_cols = slice(n, n + 2) if flex else None
        n += 2 if flex else 0
        return cls(intrinsics, camera_pose, shot_pose, np.asarray(shot_active, dtype=bool), n, flex_cols)


@dataclass
class State:
    """Cameras, target poses and (for a flexible target) its flex terms at one parameter vector.

    ``flex_m``: (2,) ``(c_x, c_y)`` of :func:`scanrig.targets.target.flex_shape`, metres; None
    for a rigid target.
    """

    cameras: list[Camera]
    world_from_target: list[RigidTransform | None]
    flex_m: np.ndarray | None = None


def bend(p_target: np.ndarray, flex_dir: np.ndarray | None, flex_m: np.ndarray | None) -> np.ndarray:
    """Target points bent by the flex terms.

    Parameters
    ----------
    p_target : ndarray of shape (N, 3)
        Flat target points, target frame, metres.
    flex_dir : ndarray of shape (N, 3, 2) or None
        Their :meth:`~scanrig.targets.Target.flex_directions`.
    flex_m : ndarray of shape (2,) or None
        ``(c_x, c_y)``, metres; None for a rigid target (``p_target`` is returned as is).

    Returns
    -------
    ndarray of shape (N, 3)
    """
    return p_target if flex_m is None else p_target + flex_dir @ flex_m


def pack(state: State, layout: Layout) -> np.ndarray:
    """Parameter vector of a state."""
    x = np.zeros(layout.size)
    for cam, index, pose in zip(state.cameras, layout.intrinsics, layout.camera_pose):
        free = index >= 0
        x[index[free]] = cam.params[free]
        if pose is not None:
            x[pose] = np.concatenate([cam.cam_from_world.rvec, cam.cam_from_world.t])
    for wt, pose in zip(state.world_from_target, layout.shot_pose):
        if pose is not None:
            x[pose] = np.concatenate([wt.rvec, wt.t])
    if layout.flex is not None:
        x[layout.flex] = state.flex_m
    return x


def unpack(x: np.ndarray, layout: Layout, template: State) -> State:
    """State at parameter vector ``x``; fixed values come from ``template``."""
    poses = [wt if pose is None else RigidTransform.from_rvec_tvec(x[pose][:3], x[pose][3:])
             for wt, pose in zip(template.world_from_target, layout.shot_pose)]
    flex_m = None if layout.flex is None else x[layout.flex].copy()
    return State(unpack_cameras(x, layout, template.cameras), poses, flex_m)


def unpack_cameras(x: np.ndarray, layout: Layout, cameras: list[Camera]) -> list[Camera]:
    """Cameras at parameter vector ``x``; fixed values come from ``cameras``."""
    out = []
    for cam, index, pose in zip(cameras, layout.intrinsics, layout.camera_pose):
        params = cam.params.copy()
        free = index >= 0
        params[free] = x[index[free]]
        cam_from_world = cam.cam_from_world if pose is None else RigidTransform.from_rvec_tvec(x[pose][:3], x[pose][3:])
        out.append(Camera(cam.name, cam.model, params, cam.width, cam.height, cam_from_world))
    return out


def project_observations(state: State, obs: Observations, p_target: np.ndarray) -> np.ndarray:
    """(N, 2) predicted pixels of every observation (NaN behind a camera or for inactive shots)."""
    p_world = np.full_like(p_target, np.nan)
    for s in np.unique(obs.shot):
        rows = obs.shot == s
        pose = state.world_from_target[s]
        if pose is not None:
            p_world[rows] = pose.apply(p_target[rows])
    q = np.full((len(obs), 2), np.nan)
    for c, cam in enumerate(state.cameras):
        rows = obs.camera == c
        if np.any(rows):
            q[rows] = cam.project(p_world[rows])
    return q


def rotation_jacobians(rvecs: np.ndarray):
    """Rotation matrices and the factor ``M`` of d(R p)/d rvec = -R [p]x M, for many rotations.

    The batched form of :func:`scanrig.geometry.transform.rotated_point_jacobian_rvec`
    (Gallego & Yezzi 2015): one vectorised call for every shot instead of one call per shot.

    Parameters
    ----------
    rvecs : ndarray of shape (K, 3)

    Returns
    -------
    R, M : ndarray of shape (K, 3, 3)
    """
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(rvecs).as_matrix().reshape(-1, 3, 3)
    theta2 = np.sum(rvecs ** 2, axis=1)
    M = np.broadcast_to(np.eye(3), R.shape).copy()
    big = theta2 >= 1e-24
    v = rvecs[big]
    M[big] = (v[:, :, None] * v[:, None, :]
              + (np.swapaxes(R[big], 1, 2) - np.eye(3)) @ skew(v)) / theta2[big, None, None]
    return R, M


@dataclass(frozen=True)
class PriorRows:
    """Prior residual rows ``scale_px * (x[cols] - mean) / std`` appended below the pixel residuals.

    Attributes
    ----------
    cols : ndarray of int, shape (k,)
        Positions in ``x`` of the parameters with a prior.
    mean : ndarray of shape (k,)
        Prior values.
    std : ndarray of shape (k,)
        Prior standard deviations, in the parameters' units (> 0).
    """

    cols: np.ndarray
    mean: np.ndarray
    std: np.ndarray

    @classmethod
    def build(cls, cameras: list[Camera], layout: Layout, priors: dict) -> PriorRows | None:
        """Rows for ``priors`` (``camera name -> (params, params_std)``) over the free parameters
        whose prior sigma is positive; None when there are none."""
        cols, mean, std = [], [], []
        for cam, index in zip(cameras, layout.intrinsics):
            if cam.name not in priors:
                continue
            params, params_std = (np.asarray(v, dtype=float) for v in priors[cam.name])
            use = (index >= 0) & (params_std > 0)
            cols.append(index[use])
            mean.append(params[use])
            std.append(params_std[use])
        if not cols or not sum(len(c) for c in cols):
            return None
        return cls(np.concatenate(cols), np.concatenate(mean), np.concatenate(std))

    def residuals(self, x: np.ndarray, scale_px: float) -> np.ndarray:
        """(k,) rows at ``x``, in pixels (``scale_px`` = residual sigma of the pixels)."""
        return scale_px * (x[self.cols] - self.mean) / self.std

    def jacobian(self, n_params: int, scale_px: float) -> scipy.sparse.csr_matrix:
        """(k, n_params) derivative of :meth:`residuals`."""
        k = len(self.cols)
        return scipy.sparse.csr_matrix((scale_px / self.std, (np.arange(k), self.cols)), shape=(k, n_params))


class Problem:
    """Residuals and sparse Jacobian of a fixed set of observations, as a function of ``x``.

    The sparsity pattern is computed once; each evaluation only fills the non-zero values.

    Parameters
    ----------
    obs : Observations
        Observations of solved shots only.
    p_target : ndarray of shape (N, 3)
        Target coordinates of each observation.
    layout : Layout
    template : State
        Values of the parameters held fixed.
    sqrt_w : ndarray of shape (N,)
        Square roots of the observation weights.
    prior : PriorRows, optional
        Prior rows appended below the ``2N`` pixel rows.
    prior_scale_px : float
        Pixel residual sigma the prior rows are scaled with.
    flex_dir : ndarray of shape (N, 3, 2), optional
        Each point's :meth:`~scanrig.targets.Target.flex_directions`; needed when
        ``layout.flex`` is set.
    """

    def __init__(self, obs: Observations, p_target: np.ndarray, layout: Layout, template: State,
                 sqrt_w: np.ndarray, prior: PriorRows | None = None, prior_scale_px: float = 1.0,
                 flex_dir: np.ndarray | None = None):
        self.obs, self.p_target, self.layout, self.template, self.sqrt_w = obs, p_target, layout, template, sqrt_w
        self.prior, self.prior_scale_px, self.flex_dir = prior, prior_scale_px, flex_dir
        n_shots = len(layout.shot_pose)
        self._shot_rvec0 = np.zeros((n_shots, 3))
        self._shot_t0 = np.zeros((n_shots, 3))
        for s, pose in enumerate(template.world_from_target):
            if pose is not None:
                self._shot_rvec0[s], self._shot_t0[s] = pose.rvec, pose.t
        self._shot_cols = np.array([-1 if sl is None else sl.start for sl in layout.shot_pose])
        self._camera_rows = [np.flatnonzero(obs.camera == c) for c in range(len(template.cameras))]
        self._skew_p = skew(p_target)
        rows, cols = [], []
        for c, sel in enumerate(self._camera_rows):
            if len(sel) == 0:
                continue
            for block_rows, block_cols in self._column_blocks(c, sel):
                r2 = 2 * block_rows[:, None, None] + np.arange(2)[None, :, None]
                rr, cc = np.broadcast_arrays(r2, block_cols[:, None, :])
                rows.append(rr.ravel())
                cols.append(cc.ravel())
        rows = np.concatenate(rows) if rows else np.zeros(0, int)
        cols = np.concatenate(cols) if cols else np.zeros(0, int)
        order = np.lexsort((cols, rows))
        self._perm = order
        self._indices = cols[order]
        self._indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=2 * len(obs)))])

    def _column_blocks(self, c: int, sel: np.ndarray):
        """Per block kind (intrinsics, camera pose, shot pose, flex), the observation rows (k,) and
        their parameter columns (k, m) among camera c's observations ``sel``; same order as the values."""
        intr = self.layout.intrinsics[c]
        blocks = [(sel, np.broadcast_to(intr[intr >= 0], (len(sel), int(np.sum(intr >= 0)))))]
        if self.layout.camera_pose[c] is not None:
            start = self.layout.camera_pose[c].start
            blocks.append((sel, np.broadcast_to(np.arange(start, start + 6), (len(sel), 6))))
        start = self._shot_cols[self.obs.shot[sel]]
        has = start >= 0
        blocks.append((sel[has], start[has, None] + np.arange(6)[None, :]))
        if self.layout.flex is not None:
            start = self.layout.flex.start
            blocks.append((sel, np.broadcast_to(np.arange(start, start + 2), (len(sel), 2))))
        return blocks

    def state(self, x: np.ndarray) -> State:
        """Cameras and target poses at ``x``."""
        return unpack(x, self.layout, self.template)

    def _shot_params(self, x: np.ndarray):
        rvec, t = self._shot_rvec0.copy(), self._shot_t0.copy()
        for s, sl in enumerate(self.layout.shot_pose):
            if sl is not None:
                rvec[s], t[s] = x[sl][:3], x[sl][3:]
        return rvec, t

    def __call__(self, x: np.ndarray, jacobian: bool = True):
        """Weighted residuals (2N + k,) and, if ``jacobian``, the sparse Jacobian (2N + k, layout.size);
        ``k`` prior rows (0 without a prior)."""
        obs, layout = self.obs, self.layout
        cameras = unpack_cameras(x, self.layout, self.template.cameras)
        rvec, t = self._shot_params(x)
        R, M = rotation_jacobians(rvec)
        Rs = R[obs.shot]
        flex_m = None if layout.flex is None else x[layout.flex]
        p_target = bend(self.p_target, self.flex_dir, flex_m)
        p_world = np.einsum("nij,nj->ni", Rs, p_target) + t[obs.shot]
        r = np.empty((len(obs), 2))
        if not jacobian:
            for cam, sel in zip(cameras, self._camera_rows):
                r[sel] = cam.project(p_world[sel]) - obs.uv[sel]
            return self._with_prior(x, (r * self.sqrt_w[:, None]).ravel())
        skew_p = self._skew_p if flex_m is None else skew(p_target)
        J_rot = -(Rs @ skew_p @ M[obs.shot])      # d p_world / d shot rvec, (N, 3, 3)
        J_flex = None if flex_m is None else Rs @ self.flex_dir  # d p_world / d flex, (N, 3, 2)
        values = []
        for c, (cam, sel) in enumerate(zip(cameras, self._camera_rows)):
            if len(sel) == 0:
                continue
            q, J_point, J_pose, J_intr = cam.project_with_jacobians(p_world[sel])
            r[sel] = q - obs.uv[sel]
            w = self.sqrt_w[sel, None, None]
            intr = layout.intrinsics[c]
            values.append((J_intr[:, :, intr >= 0] * w).ravel())
            if layout.camera_pose[c] is not None:
                J_pose[:, :, :3] = J_pose[:, :, :3] @ _rvec_chart(cam.cam_from_world.rvec, x[layout.camera_pose[c]][:3])
                values.append((J_pose * w).ravel())
            has = self._shot_cols[obs.shot[sel]] >= 0
            J_shot = np.concatenate([J_point[has] @ J_rot[sel[has]], J_point[has]], axis=2)
            values.append((J_shot * w[has]).ravel())
            if J_flex is not None:
                values.append((J_point @ J_flex[sel] * w).ravel())
        data = np.concatenate(values)[self._perm]
        J = scipy.sparse.csr_matrix((data, self._indices, self._indptr), shape=(2 * len(obs), layout.size))
        if self.prior is not None:
            J = scipy.sparse.vstack([J, self.prior.jacobian(layout.size, self.prior_scale_px)], format="csr")
        return self._with_prior(x, (r * self.sqrt_w[:, None]).ravel()), J

    def _with_prior(self, x: np.ndarray, r: np.ndarray) -> np.ndarray:
        if self.prior is None:
            return r
        return np.concatenate([r, self.prior.residuals(x, self.prior_scale_px)])

@dataclass
class Outlier:
    """One rejected observation, for the report."""

    camera: str
    shot: str
    point_id: int
    residual_px: float


@dataclass
class BundleResult:
    """Outcome of :func:`bundle_adjust`.

    Attributes
    ----------
    state : State
        Solved cameras and target poses.
    layout : Layout
    x : ndarray
        Final parameter vector.
    obs : Observations
        The observations given.
    inliers : ndarray of bool, shape (N,)
        Observations used in the final solve.
    residuals_px : ndarray of shape (N, 2)
        Unweighted ``projected - observed`` of every observation at the solution (NaN for
        observations of unsolved shots).
    sigma_px : float
        Residual scale: ``sqrt(SSR / (2 n_inliers - n_params))`` of the weighted residuals.
    outliers : list of Outlier
    iterations : int
    jacobian : scipy.sparse matrix
        Weighted Jacobian of the final inlier residuals (for the covariance).
    """

    state: State
    layout: Layout
    x: np.ndarray
    obs: Observations
    inliers: np.ndarray
    residuals_px: np.ndarray
    sigma_px: float
    outliers: list[Outlier] = field(default_factory=list)
    iterations: int = 0
    jacobian: object = None

    def rms_px(self, camera: int | None = None) -> float:
        """RMS reprojection error over inliers (per point: sqrt(mean |e|²)), optionally of one camera."""
        rows = self.inliers if camera is None else self.inliers & (self.obs.camera == camera)
        return float(np.sqrt(np.mean(np.sum(self.residuals_px[rows] ** 2, axis=1))))


def bundle_adjust(obs: Observations, target: Target, cameras: list[Camera],
                  world_from_target: list[RigidTransform | None], reference_shot: int,
                  fixed_params: dict[str, tuple[str, ...]] | None = None, robust: bool = True,
                  max_iterations: int = 100, priors: dict | None = None) -> BundleResult:
    """Jointly refine intrinsics, camera poses and target poses.

    Parameters
    ----------
    obs : Observations
    target : Target
    cameras : list of Camera
        Initial cameras in the order of ``obs.camera_names``.
    world_from_target : list of RigidTransform or None
        Initial target pose per shot; shots with None are left out.
    reference_shot : int
        Shot whose pose is held at its given value (identity: the world frame).
    fixed_params : dict, optional
        ``camera name -> parameter names held fixed`` (e.g. ``("k3",)``).
    robust : bool
        Huber IRLS and outlier rejection (True) or plain least squares on all observations.
    max_iterations : int
        Per Levenberg–Marquardt run.
    priors : dict, optional
        ``camera name -> (params, params_std)``, each of shape (n_params,): Gaussian priors on
        that camera's free intrinsics (parameters with ``params_std`` 0 get none).

    Raises
    ------
    InputError
        If fewer residuals than unknowns remain (too few views for the model).
    EstimationError
        If the solve produces non-finite values.
    """
    shot_active = np.array([p is not None for p in world_from_target])
    layout = Layout.build(cameras, shot_active, reference_shot, fixed_params or {}, flex=target.flex)
    template = State(list(cameras), list(world_from_target), np.zeros(2) if target.flex else None)
    p_target, known = target.lookup(obs.point_id)
    flex_dir = None
    if target.flex:
        flex_dir = np.zeros((len(obs), 3, 2))
        flex_dir[known] = target.flex_directions(obs.point_id[known])
    usable = known & shot_active[obs.shot]
    x = pack(template, layout)
    prior = PriorRows.build(cameras, layout, priors or {})
    n_prior = 0 if prior is None else len(prior.cols)
    prior_scale_px = 1.0
    inliers = usable.copy()
    outliers: list[Outlier] = []
    total_iterations = 0

    def solve(x, rows, irls_weight, cost_rtol=COST_RTOL):
        sub = obs.subset(rows)
        _check_redundancy(2 * len(sub), layout.size)
        problem = Problem(sub, p_target[rows], layout, template, np.sqrt(sub.weight * irls_weight),
                          prior, prior_scale_px, _rows(flex_dir, rows))
        return levenberg_marquardt(problem, x, max_iterations, cost_rtol)

    if robust:
        for _ in range(MAX_REJECTION_ROUNDS):
            irls = np.ones(inliers.sum())
            for _ in range(IRLS_ROUNDS):
                res = solve(x, inliers, irls, IRLS_COST_RTOL)
                x, total_iterations = res.x, total_iterations + res.iterations
                norm = _residual_norms(x, layout, template, obs, p_target, flex_dir, inliers)
                scale = np.median(norm) / RAYLEIGH_MEDIAN
                new_irls = np.minimum(1.0, HUBER_SIGMAS * scale / np.maximum(norm, 1e-300))
                if np.allclose(new_irls, irls, atol=IRLS_WEIGHT_ATOL):
                    break
                irls = new_irls
            norm_all = np.full(len(obs), np.nan)
            norm_all[usable] = _residual_norms(x, layout, template, obs, p_target, flex_dir, usable)
            scale = np.median(norm_all[inliers]) / RAYLEIGH_MEDIAN
            prior_scale_px = float(scale)
            bad = inliers & (norm_all > OUTLIER_SIGMAS * scale)
            if not np.any(bad):
                break
            for i in np.flatnonzero(bad):
                outliers.append(Outlier(obs.camera_names[obs.camera[i]], obs.shot_names[obs.shot[i]],
                                        int(obs.point_id[i]), float(norm_all[i] / np.sqrt(obs.weight[i]))))
            inliers &= ~bad
    sub = obs.subset(inliers)
    dof = 2 * len(sub) + n_prior - layout.size
    # With priors the final solve runs twice: the prior rows are scaled with the pixel sigma that
    # the first run measures, so the covariance carries the prior's own variance.
    for _ in range(1 if prior is None else 2):
        res = solve(x, inliers, np.ones(inliers.sum()))
        # Rotation vectors back to at most pi (same rotations), as the cameras and the covariance's
        # users (Camera.project_with_jacobians, uncertainty) differentiate by them.
        x, total_iterations = pack(unpack(res.x, layout, template), layout), total_iterations + res.iterations
        r, J = Problem(sub, p_target[inliers], layout, template, np.sqrt(sub.weight), prior, prior_scale_px,
                       _rows(flex_dir, inliers))(x, True)
        if not np.all(np.isfinite(r)):
            raise EstimationError("bundle adjustment diverged (points behind a camera); check the target "
                                  "definition and the image order of every camera")
        sigma = float(np.sqrt(r @ r / dof))
        prior_scale_px = sigma
    state = unpack(x, layout, template)
    residuals = np.full((len(obs), 2), np.nan)
    p_usable = bend(p_target[usable], _rows(flex_dir, usable), state.flex_m)
    residuals[usable] = project_observations(state, obs.subset(usable), p_usable) - obs.uv[usable]
    return BundleResult(state, layout, x, obs, inliers, residuals, sigma, outliers, total_iterations, J)


def _rvec_chart(rvec_camera: np.ndarray, rvec_x: np.ndarray) -> np.ndarray:
    """(3, 3) ``d rvec_camera / d rvec_x`` for two rotation vectors of the same rotation.

    :meth:`Camera.project_with_jacobians` differentiates by the camera's own rotation vector,
    which is at most pi long, while the solver steps the one in ``x``, which may have grown past pi
    (the same rotation: the axis reversed and the angle 2 pi less). By d(R p)/d rvec = -R [p]x M
    (:func:`rotation_jacobians`), the factor is ``M(rvec_camera)⁻¹ M(rvec_x)``: the identity (to
    round-off) while the two agree. Without it, a camera rotated by nearly 180 deg from the world
    frame whose vector crossed pi during the solve had two of its rotation columns mirrored, so
    the solver stopped short of the minimum.
    """
    _, M = rotation_jacobians(np.stack([rvec_camera, rvec_x]))
    return np.linalg.solve(M[0], M[1])


def _residual_norms(x, layout, template, obs, p_target, flex_dir, rows) -> np.ndarray:
    """Weighted residual norms (pixels × sqrt(weight)) of the selected observations."""
    state = unpack(x, layout, template)
    sub = obs.subset(rows)
    q = project_observations(state, sub, bend(p_target[rows], _rows(flex_dir, rows), state.flex_m))
    return np.linalg.norm(q - sub.uv, axis=1) * np.sqrt(sub.weight)


def _rows(flex_dir: np.ndarray | None, rows) -> np.ndarray | None:
    """The selected rows of ``flex_dir`` (None for a rigid target)."""
    return None if flex_dir is None else flex_dir[rows]


def _check_redundancy(n_residuals: int, n_params: int) -> None:
    if n_residuals <= n_params:
        raise InputError(
            f"calibration has {n_residuals} residuals for {n_params} unknowns; add views or use a simpler "
            "camera model (fewer distortion coefficients)"
        )
