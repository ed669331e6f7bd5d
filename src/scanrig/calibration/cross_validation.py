"""Cross-validation: do independent halves of the views differ as their σ says?

The shots are split into two halves four ways (:data:`SPLITS`: odd/even, two more interleaved
patterns, and the first half of the session against the second), and the two halves of each
split are calibrated apart
(:func:`scanrig.calibration.pipeline.calibrate` solves them); this module compares the two
solutions of a split and predicts their difference from *their own* covariances. Since the
halves share no observation, their errors are independent and the covariance of the difference
is ``Σ_A + Σ_B`` propagated to pixels.

The comparison is gauge-free: each half has its own world frame (the target at its own
reference shot), so world coordinates cannot be compared. Instead the same 3-D points are fixed
in the frame of the rig's *reference camera* (the first camera) and every camera projects them
through its own intrinsics and its pose relative to the reference camera,
``cam_from_ref = cam_from_world ∘ ref_from_world⁻¹``, in which the world frame cancels. For the
reference camera itself only its intrinsics remain (the pose terms cancel exactly).

The points are those seen at the grid pixels (:data:`~scanrig.calibration.uncertainty.MAP_SAMPLES`)
that lie inside the convex hull of the corners *both* halves observed in that camera, at the
camera's working distance: where both halves have data, as in use. Outside the hull a
polynomial distortion model is an extrapolation and the halves may legitimately disagree by
far more than any σ computed at the data.

Reported per camera and split: ``measured_px``, the RMS over those points of the difference
between the halves' projections; ``predicted_px``, the RMS their covariances predict there
(``sqrt(mean trace(G_A Σ_A G_Aᵀ + G_B Σ_B G_Bᵀ))``, ``G`` the Jacobian of a projection with
respect to the half's parameters, each half's in its own world frame); and ``ratio``, the
difference in units of its predicted σ: the pixel differences whitened by that covariance,
``sqrt(χ² / dof)`` over its ``dof`` independent directions. The plain
``measured_px / predicted_px`` is a poor judge: one or two directions (the principal point)
carry most of the predicted variance, so it scatters 0.1-2.8 over clean simulated sessions even
when the σ are right, whereas ``ratio`` averages 7-12 directions: ``ratio² dof`` is then
chi-square over ``dof`` directions.

One split's ``χ²`` still has few directions (below 0.5 by chance for ~1 % of cameras at 9
directions), so the splits are pooled (:func:`combine_splits`), ``sqrt(Σ χ² / Σ dof)``. The
splits' contrasts are orthogonal (over any multiple of 8 shots), so with shots of equal information
their differences would be independent; real shots differ in what they show, so they are
somewhat correlated (``benchmarks/bench_cross_validation.py --correlation``). Interleaved halves
of shots taken in sequence (a video) share where the board was, and so what is wrong with such
views; the first and second halves of the session do not, which is why that split is there.
A ``ratio`` above :data:`RATIO_WARN` in any split (and so in the pooled one, which cannot exceed
the largest) means the stated uncertainty is too small: the chance of that at 9 directions is
1e-13. :func:`cross_validation_warnings` says so in one line per camera, naming the split.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scanrig.calibration.bundle import BundleResult, rotation_jacobians
from scanrig.calibration.uncertainty import MAP_SAMPLES, grid_points_cam
from scanrig.geometry.transform import skew

#: ``ratio`` above this is warned about. When the σ are right, ``ratio²`` is chi-square over
#: ``dof`` directions divided by ``dof``; with 4 directions it exceeds 3² = 9 with probability
#: 3e-7, with 9 directions 1e-13: a warning means a real excess.
RATIO_WARN = 3.0


@dataclass(frozen=True)
class Split:
    """A split of the session's shots (in its natural order) into two halves.

    Attributes
    ----------
    halves : str
        The two halves in words, for the warning: "the odd and even shots".
    pattern : tuple of 4 int or None
        The half (0 or 1) of each shot index modulo 4; None for the first half of the session
        against the second.
    """

    halves: str
    pattern: tuple | None = None

    def half_of(self, n_shots: int) -> np.ndarray:
        """(n_shots,) int: the half (0 or 1) of each shot."""
        index = np.arange(n_shots)
        if self.pattern is None:
            return (2 * index >= n_shots).astype(int)
        return np.asarray(self.pattern)[index % 4]


#: The splits of the shots into two halves. As ±1 contrasts these are four of the Walsh
#: (Hadamard) patterns, from the highest frequency (odd/even) to the lowest (first/second halves),
#: orthogonal to each other over a session of 8, 16, ... shots. The first three interleave (each
#: half has every other shot, or pair of shots, of the whole sequence); the last is blocked. Shots
#: taken in sequence (a video, a hand-held sweep) share, between neighbours, where the board was;
#: errors tied to that (corner bias with the view angle, flex, a model that fits one region) are
#: shared by interleaved halves and cancel in their difference, but differ between the first and
#: second halves of the session.
SPLITS = {"odd/even": Split("the odd and even shots", (0, 1, 0, 1)),
          "pairs": Split("alternate pairs of shots (1-2 and 3-4 of every four)", (0, 0, 1, 1)),
          "staggered pairs": Split("the outer and inner shots of every four (1, 4 and 2, 3)", (0, 1, 1, 0)),
          "first/second halves": Split("the first and second halves of the shots")}
#: Pixel-space directions whose singular value is below this fraction of the largest are left
#: out of the whitened ratio: they carry less than 1e-6 of the largest variance, where the
#: difference would be second-order terms and round-off rather than data. (The two halves'
#: directions nearly coincide, so half of them fall below this.)
WHITEN_RTOL = 1e-3
#: Fewest grid points inside both halves' hulls for a camera to be compared.
MIN_COMMON_POINTS = 4
#: What a ratio above :data:`RATIO_WARN` may come from and what to do, for the report.
CAUSES = ("systematic corner error (detector, blur, a target whose printed size or flatness differs "
          "from target.toml): check the residual plots for patterns",
          "board flex (a foam or card board bends by ~1 mm): use a rigid board, or set flex = true in "
          "target.toml (planar boards) to estimate the bend",
          "too few or too similar views: add views at other tilts, distances and image positions",
          "an over-parameterised model (distortion terms the views cannot pin down): use a simpler "
          "model (--model opencv4)")


@dataclass(frozen=True)
class CameraCrossValidation:
    """The comparison of one camera's half solutions (of one split, or pooled over the splits).

    Attributes
    ----------
    measured_px : float
        RMS difference of the halves' projections over the common points, pixels (pooled: over
        every split's points).
    predicted_px : float
        RMS difference their covariances predict there, pixels.
    max_px : float
        Largest difference over the common points, pixels.
    n_points : int
        Grid points inside both halves' corner hulls (pooled: summed over the splits).
    ratio : float
        The difference in units of its predicted σ: ``sqrt(χ² / dof)``, χ² of the pixel
        differences whitened by their predicted covariance over its ``dof`` independent
        directions. Near 1 when the σ are right (``ratio² dof`` is then chi-square over ``dof``
        directions). (``measured_px / predicted_px`` is dominated by the one or two largest
        directions, typically the principal point, so it scatters 0.1-2.8 between clean
        sessions.) Pooled: ``sqrt(Σ χ² / Σ dof)`` over the splits. NaN when nothing is free.
    dof : int
        Independent directions the ratio is taken over (free intrinsics plus 6 for the pose
        relative to the reference camera, less those the image cannot see; pooled: summed over
        the splits).
    """

    measured_px: float
    predicted_px: float
    max_px: float
    n_points: int
    ratio: float
    dof: int


@dataclass(frozen=True)
class CrossValidation:
    """Cross-validation of a calibration: its halves' differences per camera.

    Attributes
    ----------
    cameras : dict
        ``camera -> CameraCrossValidation``, or None where the halves' corners have fewer than
        :data:`MIN_COMMON_POINTS` grid points in common (in every split).
    reference_camera : str
        Camera whose frame holds the compared 3-D points.
    splits : dict
        Pooled over splits (:func:`combine_splits`): ``split name -> {camera ->
        CameraCrossValidation or None}``, each split's own figures, for the splits whose halves
        could be solved (in :data:`SPLITS` order). Empty for one split's comparison.
    """

    cameras: dict
    reference_camera: str
    splits: dict = field(default_factory=dict)


def split_halves(n_shots: int, split: Split) -> tuple[np.ndarray, np.ndarray]:
    """The shot indices of the two halves of a split.

    Parameters
    ----------
    n_shots : int
    split : Split
        A value of :data:`SPLITS`.

    Returns
    -------
    half0, half1 : ndarray of int
    """
    half = split.half_of(n_shots)
    return np.flatnonzero(half == 0), np.flatnonzero(half == 1)


def combine_splits(per_split: dict) -> CrossValidation:
    """One check per camera from every split's comparison: χ² and dof summed, RMS over all points.

    Parameters
    ----------
    per_split : dict
        ``split name -> CrossValidation`` (:func:`compare_halves`), at least one, same cameras.
    """
    first = next(iter(per_split.values()))
    cameras = {name: _pool([cv.cameras[name] for cv in per_split.values() if cv.cameras[name] is not None])
               for name in first.cameras}
    return CrossValidation(cameras, first.reference_camera,
                           {split: cv.cameras for split, cv in per_split.items()})


def _pool(checks: list) -> CameraCrossValidation | None:
    """Several splits' checks of one camera as one: ``sqrt(Σ χ² / Σ dof)``; None when there are none."""
    if not checks:
        return None
    n = np.array([c.n_points for c in checks])
    dof = sum(c.dof for c in checks)
    chi2 = sum(c.ratio ** 2 * c.dof for c in checks if c.dof)
    return CameraCrossValidation(float(np.sqrt(np.sum(n * [c.measured_px ** 2 for c in checks]) / n.sum())),
                                 float(np.sqrt(np.sum(n * [c.predicted_px ** 2 for c in checks]) / n.sum())),
                                 max(c.max_px for c in checks), int(n.sum()),
                                 float(np.sqrt(chi2 / dof)) if dof else float("nan"), dof)


def compare_halves(full: BundleResult, halves: list[BundleResult], covariances: list[np.ndarray],
                   working_distance_m: dict, samples=MAP_SAMPLES) -> CrossValidation:
    """Measured and predicted difference between two independent half solutions, per camera.

    Parameters
    ----------
    full : BundleResult
        Solution from all views: defines the compared points.
    halves : list of two BundleResult
        Solutions from the two halves of the shots (same cameras, same order).
    covariances : list of two ndarray of shape (n_params, n_params)
        Their parameters' covariances (:func:`scanrig.calibration.uncertainty.parameter_covariance`).
    working_distance_m : dict
        ``camera -> depth (m)`` at which the points are placed.
    samples : (int, int)
        Grid pixels per image side.
    """
    ref = 0
    out = {}
    for c, cam in enumerate(full.state.cameras):
        p_ref = common_points(full, halves, c, working_distance_m[cam.name], samples)
        if p_ref is None:
            out[cam.name] = None
            continue
        projected, modes = [], []
        for half, cov in zip(halves, covariances):
            q_half, G, cols = _projection_jacobian(half, c, ref, p_ref)
            projected.append(q_half)
            modes.append(_sigma_modes(G, cov[np.ix_(cols, cols)]))
        diff, modes = projected[1] - projected[0], np.concatenate(modes, axis=1)
        seen = np.all(np.isfinite(diff), axis=1)          # a half may put a point behind the camera
        if np.count_nonzero(seen) < MIN_COMMON_POINTS:
            out[cam.name] = None
            continue
        k = modes.shape[1]  # 0 when nothing about this camera is free
        seen_modes = modes.reshape(len(diff), 2, k)[seen].reshape(2 * np.count_nonzero(seen), k)
        out[cam.name] = _judge(diff[seen], seen_modes)
    return CrossValidation(out, full.state.cameras[ref].name)


def common_points(full: BundleResult, halves: list[BundleResult], camera: int, depth_m: float,
                  samples=MAP_SAMPLES) -> np.ndarray | None:
    """(n, 3) points in the reference camera's frame (m) that a camera's halves are compared at:
    those at ``depth_m`` behind the grid pixels inside the hull of the corners every half saw in
    that camera (None when fewer than :data:`MIN_COMMON_POINTS`)."""
    cam = full.state.cameras[camera]
    q, p_cam = grid_points_cam(cam, depth_m, samples)
    common = np.all(np.isfinite(p_cam), axis=1)
    for half in halves:
        common &= _inside_hull(_observed_pixels(half, camera), q)
    if np.count_nonzero(common) < MIN_COMMON_POINTS:
        return None
    ref_from_cam = full.state.cameras[0].cam_from_world @ cam.cam_from_world.inverse()
    return ref_from_cam.apply(p_cam[common])


def whitening(modes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The independent directions of a pixel difference whose covariance is ``modes modesᵀ``.

    Parameters
    ----------
    modes : ndarray of shape (2n, m)

    Returns
    -------
    U : ndarray of shape (2n, dof)
        Orthonormal directions, those with singular values above :data:`WHITEN_RTOL` of the largest.
    s : ndarray of shape (dof,)
        Their standard deviations, pixels: ``U.T @ d / s`` is the whitened difference.
    """
    U, s, _ = np.linalg.svd(modes, full_matrices=False)
    keep = s > WHITEN_RTOL * s[0] if len(s) and s[0] > 0 else np.zeros(len(s), dtype=bool)
    return U[:, keep], s[keep]


def _sigma_modes(G: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(2n, k) pixel effect of 1 sigma along each principal direction of ``cov``: ``G L`` with
    ``L Lᵀ = cov``, so that the pixels' covariance is ``(G L)(G L)ᵀ``.

    Parameters
    ----------
    G : ndarray of shape (n, 2, k)
    cov : ndarray of shape (k, k)
    """
    evals, evecs = np.linalg.eigh(cov)
    return G.reshape(len(G) * 2, G.shape[2]) @ (evecs * np.sqrt(np.maximum(evals, 0.0)))


def _judge(diff_px: np.ndarray, modes: np.ndarray) -> CameraCrossValidation:
    """Measured against predicted difference of the halves' projections.

    Each half's covariance is propagated with its own Jacobian (each half has its own world
    frame, so its pose derivatives are taken in that frame; only the pixels are common).

    Parameters
    ----------
    diff_px : ndarray of shape (n, 2)
        Second minus first half's projection of each common point, pixels.
    modes : ndarray of shape (2n, m)
        Both halves' :func:`_sigma_modes` side by side: the difference's covariance is
        ``modes modesᵀ`` (``Σ_A + Σ_B`` in pixels).
    """
    n = len(diff_px)
    d = diff_px.ravel()
    U, s = whitening(modes)
    z = (U.T @ d) / s
    dof = len(s)
    return CameraCrossValidation(float(np.sqrt(d @ d / n)), float(np.sqrt(np.sum(modes ** 2) / n)),
                                 float(np.max(np.linalg.norm(diff_px, axis=1))), n,
                                 float(np.sqrt(z @ z / dof)) if dof else float("nan"), dof)


def _observed_pixels(result: BundleResult, camera: int) -> np.ndarray:
    """(n, 2) pixels of a camera's inlier observations in one solution."""
    return result.obs.uv[result.inliers & (result.obs.camera == camera)]


def _inside_hull(points: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(m,) whether each pixel ``q`` lies in the convex hull of ``points`` (False for all when the
    points span no area)."""
    from scipy.spatial import Delaunay, QhullError

    try:
        return Delaunay(points).find_simplex(q) >= 0
    except (QhullError, ValueError):
        return np.zeros(len(q), dtype=bool)


def _projection_jacobian(result: BundleResult, camera: int, ref: int, p_ref: np.ndarray):
    """Pixels of points fixed in the reference camera's frame, and their Jacobian.

    The point goes to the world with this solution's reference pose, ``p_world = R_refᵀ (p_ref -
    t_ref)``, and is projected by ``camera``. Its derivatives with respect to the reference pose
    are ``[p_world]× M`` (rotation vector; ``d(R p)/dr = -R [p]× M``) and ``-R_refᵀ`` (translation);
    when ``camera`` is the reference they cancel those of its own pose exactly, so both are left
    out (summed, they would leave round-off that the whitened ratio would read as data).

    Returns
    -------
    q : ndarray of shape (n, 2)
    G : ndarray of shape (n, 2, k)
        ``dq / dx[cols]``.
    cols : list of int
        The parameter-vector positions ``G`` differentiates by (free intrinsics, camera pose,
        reference pose).
    """
    layout = result.layout
    cam, ref_cam = result.state.cameras[camera], result.state.cameras[ref]
    p_world = ref_cam.cam_from_world.inverse().apply(p_ref)
    q, J_point, J_pose, J_intr = cam.project_with_jacobians(p_world)
    index = layout.intrinsics[camera]
    free = index >= 0
    cols = list(index[free])
    blocks = [J_intr[:, :, free]]
    pose_cols = {}
    for c, J in ((camera, J_pose), (ref, None)) if camera != ref else ():
        if layout.camera_pose[c] is None:
            continue
        if J is None:
            R, M = rotation_jacobians(ref_cam.cam_from_world.rvec[None, :])
            dp_drvec = skew(p_world) @ M[0]
            dp_dt = np.broadcast_to(-R[0].T, dp_drvec.shape)
            J = J_point @ np.concatenate([dp_drvec, dp_dt], axis=2)
        start = layout.camera_pose[c].start
        pose_cols[start] = pose_cols[start] + J if start in pose_cols else J
    for start, J in pose_cols.items():
        cols += list(range(start, start + 6))
        blocks.append(J)
    return q, np.concatenate(blocks, axis=2), cols


def cross_validation_warnings(cv: CrossValidation | None) -> list[str]:
    """One line per camera whose ``ratio`` exceeds :data:`RATIO_WARN` in some split (or, for one
    split's comparison, in it), naming the split whose halves differ most."""
    if cv is None:
        return []
    lines = []
    for name, pooled in cv.cameras.items():
        split, worst = _worst_split(cv, name)
        if worst is None or not worst.ratio > RATIO_WARN:
            continue
        n_splits = sum(cameras[name] is not None for cameras in cv.splits.values())
        also = (f"; pooled over the {n_splits} splits into halves {pooled.ratio:.1f} x ({pooled.dof} directions)"
                if n_splits > 1 else "")
        shared = (" (errors shared by views taken in sequence: where the board was, its view angle, its flex)"
                  if SPLITS[split].pattern is None else "")
        lines.append(f"{name}: {SPLITS[split].halves} differ by {worst.ratio:.1f} x "
                     f"their stated sigma ({worst.dof} directions, RMS {worst.measured_px:.3g} px, predicted "
                     f"{worst.predicted_px:.3g} px){also}: its sigmas are too small{shared}; likely systematic corner "
                     "error, board flex, too few or too similar views, or too many distortion terms (what to do: "
                     "calibration_report/summary.txt)")
    return lines


def _worst_split(cv: CrossValidation, camera: str) -> tuple[str, CameraCrossValidation | None]:
    """The split (name) whose halves differ most for a camera, in σ, and its figures; for one
    split's comparison (no ``splits``) that comparison, named odd/even."""
    checks = [(split, cameras[camera]) for split, cameras in cv.splits.items() if cameras[camera] is not None]
    if not checks:
        return "odd/even", cv.cameras[camera]
    return max(checks, key=lambda check: np.nan_to_num(check[1].ratio, nan=-1.0))
