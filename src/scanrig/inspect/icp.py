"""Point-to-plane ICP with robust weights, so that real bumps, dents and outliers do not pull the fit.

Each iteration matches every cloud point to the plane of its nearest CAD triangle, weights the
signed point-to-plane residuals ``r`` and solves the linearised 6-parameter least squares (small
rotation, translation). The weights are Tukey's biweight with a scale from the median absolute
residual (1.4826 MAD, the normal-consistent estimate), so points further than ~4.7 noise sigmas
from the surface, which is where a 0.1 mm bump on a 20 um scan lies, get no weight at all. The
coarse stage uses trimmed weights instead (the closest fraction of the points), which tolerate a
start far from the answer. Open3D has point-to-plane ICP with robust kernels too, but it is an
optional extra and does not expose the per-point weights this module reports.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from scanrig.geometry.uncertainty import MAD_TO_SIGMA
from scanrig.inspect.closest import CadIndex

#: Tukey biweight tuning constant, in robust sigmas (95 % efficiency for Gaussian noise).
TUKEY_C = 4.685
#: Iterations stop when the update moves no point of the cloud by more than this fraction of its size.
STEP_TOL = 1e-9
#: Iteration limit.
MAX_ITERATIONS = 60
#: After the first iteration, nearest samples are searched only within BOUND_FACTOR x the largest
#: kept residual plus BOUND_SPACINGS sample spacings.
BOUND_FACTOR = 3.0
BOUND_SPACINGS = 4.0
#: Levenberg damping relative to the normal matrix's trace (keeps a plane-only scan solvable).
DAMPING = 1e-12

WeightFn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class IcpResult:
    """Outcome of :func:`robust_icp`.

    Attributes
    ----------
    cad_from_cloud : (4, 4) float array
        Maps cloud points into the CAD frame, metres.
    residual_rms_m : float
        Weighted RMS of the point-to-plane residuals at the end, metres (the alignment's residual).
    inlier_fraction : float
        Fraction of the points with a non-zero weight at the end (the overlap).
    weights : (N,) float array
        Final weights in [0, 1].
    iterations : int
        Iterations run.
    constraint : float
        Smallest over largest eigenvalue of the last step's normal matrix, rotations scaled by
        ``size_m``: near 0 when the kept points leave a motion free (a single plane, a cylinder).
    """

    cad_from_cloud: np.ndarray
    residual_rms_m: float
    inlier_fraction: float
    weights: np.ndarray
    iterations: int
    constraint: float


def tukey_weights(residual_m: np.ndarray, floor_m: float = 0.0) -> np.ndarray:
    """Tukey biweight of residuals with scale ``max(1.4826 median|r|, floor_m)``.

    Parameters
    ----------
    residual_m : (N,) float array
        Signed residuals, metres.
    floor_m : float
        Smallest scale, metres (a noise-free scan would otherwise reach zero).

    Returns
    -------
    (N,) float array
        Weights in [0, 1]; zero beyond ``TUKEY_C`` scales.
    """
    scale = max(MAD_TO_SIGMA * float(np.median(np.abs(residual_m))), floor_m)
    u = residual_m / (TUKEY_C * scale) if scale > 0 else np.zeros_like(residual_m)
    return np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)


def trimmed_weights(keep: float) -> WeightFn:
    """Weights 1 for the ``keep`` fraction of the points closest to the surface, 0 for the rest
    (and for points with no surface within the search bound, whose residual is infinite)."""
    def weights(residual_m: np.ndarray) -> np.ndarray:
        a = np.abs(residual_m)
        finite = np.isfinite(a)
        # infinite residuals rank last: the quantile of the finite ones never reads inf - inf
        cut = np.quantile(np.where(finite, a, np.finfo(np.float64).max), keep)
        return ((a <= cut) & finite).astype(np.float64)
    return weights


def robust_icp(points_m: np.ndarray, index: CadIndex, cad_from_cloud: np.ndarray, *,
               weight_fn: WeightFn | None = None, size_m: float = 1.0,
               max_iterations: int = MAX_ITERATIONS) -> IcpResult:
    """Refine ``cad_from_cloud`` by robust point-to-plane ICP.

    Parameters
    ----------
    points_m : (N, 3) float array
        Cloud points, cloud frame, metres.
    index : CadIndex
        The CAD surface.
    cad_from_cloud : (4, 4) float array
        Starting transform.
    weight_fn : callable, optional
        Residuals ``(N,)`` -> weights ``(N,)``; default :func:`tukey_weights` with a scale floor of
        ``1e-7 size_m``.
    size_m : float
        Size of the part, metres: sets the convergence test and the default scale floor.
    max_iterations : int
        Iteration limit.

    Returns
    -------
    IcpResult
    """
    if weight_fn is None:
        def weight_fn(r):
            return tukey_weights(r, floor_m=1e-7 * size_m)
    R, t = cad_from_cloud[:3, :3].copy(), cad_from_cloud[:3, 3].copy()
    bound_m = np.inf
    iterations, a = 0, np.eye(6)
    for iterations in range(1, max_iterations + 1):
        p = points_m @ R.T + t
        r, w, normal = _weighted_residuals(p, index, weight_fn, bound_m)
        if not (w > 0).any():   # no point within the search bound of the surface: nothing to fit
            break
        centre = np.average(p, axis=0, weights=w)
        # rotate about the weighted centre, so that rotation and translation decouple
        jac = np.hstack([np.cross(p - centre, normal), normal])           # d r / d(omega, dt)
        a = (jac * w[:, None]).T @ jac
        b = (jac * w[:, None]).T @ np.where(w > 0, r, 0.0)
        step = -np.linalg.solve(a + DAMPING * np.trace(a) * np.eye(6), b)
        dR = Rotation.from_rotvec(step[:3]).as_matrix()
        R, t = dR @ R, dR @ (t - centre) + centre + step[3:]
        # Points far beyond the largest kept residual cannot come back into the fit this step;
        # searching only near the surface spares the KD-tree its slowest queries.
        bound_m = BOUND_FACTOR * float(np.max(np.abs(r[w > 0]), initial=0.0)) + BOUND_SPACINGS * index.spacing_m
        if np.linalg.norm(step[:3]) * size_m + np.linalg.norm(step[3:]) < STEP_TOL * size_m:
            break
    r, w, _ = _weighted_residuals(points_m @ R.T + t, index, weight_fn, bound_m)
    kept = w > 0
    rms = float(np.sqrt(np.sum(w[kept] * r[kept] ** 2) / np.sum(w[kept]))) if kept.any() else float("inf")
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = R, t
    scale = np.r_[np.full(3, 1.0 / size_m), np.ones(3)]
    eig = np.linalg.eigvalsh(a * np.outer(scale, scale))
    constraint = float(eig[0] / eig[-1]) if eig[-1] > 0 else 0.0
    return IcpResult(matrix, rms, float(np.mean(w > 0)), w, iterations, constraint)


def _weighted_residuals(p, index, weight_fn, bound_m):
    """Point-to-plane residuals (inf where no surface is within ``bound_m``), weights and normals."""
    normal, offset = index.nearest_planes(p, bound_m)
    r = np.einsum("ij,ij->i", normal, p) - offset
    r = np.where(np.isfinite(offset), r, np.inf)
    return r, weight_fn(r), normal
