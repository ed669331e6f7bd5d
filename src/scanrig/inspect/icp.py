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
    """Tukey biweight of residuals with scale ``max(1.4826 median|r|, floor_m)``, per row.

    Parameters
    ----------
    residual_m : (..., N) float array
        Signed residuals, metres; each row (last axis) gets its own scale.
    floor_m : float
        Smallest scale, metres (a noise-free scan would otherwise reach zero).

    Returns
    -------
    (..., N) float array
        Weights in [0, 1]; zero beyond ``TUKEY_C`` scales.
    """
    scale = np.maximum(MAD_TO_SIGMA * np.median(np.abs(residual_m), axis=-1, keepdims=True), floor_m)
    u = np.divide(residual_m, TUKEY_C * scale, out=np.zeros_like(residual_m), where=scale > 0)
    return np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)


def trimmed_weights(keep: float) -> WeightFn:
    """Weights 1 for the ``keep`` fraction of each row's points closest to the surface, 0 for the
    rest (and for points with no surface within the search bound, whose residual is infinite)."""
    def weights(residual_m: np.ndarray) -> np.ndarray:
        a = np.abs(residual_m)
        finite = np.isfinite(a)
        # infinite residuals rank last: the quantile of the finite ones never reads inf - inf
        cut = np.quantile(np.where(finite, a, np.finfo(np.float64).max), keep, axis=-1, keepdims=True)
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
        Residuals ``(..., N)`` -> weights ``(..., N)``, row by row; default :func:`tukey_weights`
        with a scale floor of ``1e-7 size_m``.
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
    trial = icp_trials(points_m, index, cad_from_cloud[None], weight_fn=weight_fn, size_m=size_m,
                       max_iterations=max_iterations)
    matrix = trial.cad_from_cloud[0]
    r, _ = _plane_residuals(points_m @ matrix[:3, :3].T + matrix[:3, 3], index, trial.bound_m[0])
    w = weight_fn(r)
    kept = w > 0
    rms = float(np.sqrt(np.sum(w[kept] * r[kept] ** 2) / np.sum(w[kept]))) if kept.any() else float("inf")
    scale = np.r_[np.full(3, 1.0 / size_m), np.ones(3)]
    eig = np.linalg.eigvalsh(trial.normal_matrix[0] * np.outer(scale, scale))
    constraint = float(eig[0] / eig[-1]) if eig[-1] > 0 else 0.0
    return IcpResult(matrix, rms, float(np.mean(w > 0)), w, int(trial.iterations[0]), constraint)


@dataclass(frozen=True)
class IcpTrials:
    """Outcome of :func:`icp_trials`, one entry per start.

    Attributes
    ----------
    cad_from_cloud : (S, 4, 4) float array
    bound_m : (S,) float array
        Search bound of the nearest samples for the next iteration, metres.
    normal_matrix : (S, 6, 6) float array
        Weighted normal matrix of the last step (the identity where no step was taken).
    iterations : (S,) int array
    """

    cad_from_cloud: np.ndarray
    bound_m: np.ndarray
    normal_matrix: np.ndarray
    iterations: np.ndarray


def icp_trials(points_m: np.ndarray, index: CadIndex, starts: np.ndarray, *, weight_fn: WeightFn,
               size_m: float, max_iterations: int) -> IcpTrials:
    """Point-to-plane ICP of one cloud from several starts at once (the loop of :func:`robust_icp`).

    Each iteration matches every point to the plane of its nearest CAD sample, weights the
    residuals (``weight_fn``, row by row), and solves the linearised 6-parameter least squares
    about the weighted centre. A start stops when no point has weight (no point within the
    search bound of the surface) or when its step moves no point by more than ``STEP_TOL``
    times ``size_m``. Every start's arithmetic is its own; they share the iterations' array
    operations, so that the coarse search's hundred-odd starts on a few hundred points cost a
    few array operations per iteration instead of a few hundred (the nearest-sample search runs
    per start, as each has its own search bound).

    Parameters
    ----------
    points_m : (N, 3) float array
        Cloud points, cloud frame, metres.
    index : CadIndex
    starts : (S, 4, 4) float array
        Starting ``cad_from_cloud`` transforms.
    weight_fn : callable
        Residuals ``(k, N)`` -> weights ``(k, N)``, each row on its own.
    size_m : float
    max_iterations : int

    Returns
    -------
    IcpTrials
    """
    n_starts = len(starts)
    rotation, shift = starts[:, :3, :3].copy(), starts[:, :3, 3].copy()
    bound_m = np.full(n_starts, np.inf)
    normal_matrix = np.broadcast_to(np.eye(6), (n_starts, 6, 6)).copy()
    iterations = np.zeros(n_starts, dtype=int)
    active = np.arange(n_starts)
    for iteration in range(1, max_iterations + 1):
        iterations[active] = iteration
        p = points_m @ rotation[active].transpose(0, 2, 1) + shift[active, None]        # (k, N, 3)
        residuals = [_plane_residuals(q, index, b) for q, b in zip(p, bound_m[active])]
        r, normal = np.stack([r for r, _ in residuals]), np.stack([n for _, n in residuals])
        w = weight_fn(r)
        fits = (w > 0).any(axis=1)   # no point within the search bound of the surface: nothing to fit
        if not fits.all():
            active, p, normal, r, w = active[fits], p[fits], normal[fits], r[fits], w[fits]
            if active.size == 0:
                break
        centre = np.einsum("kn,kni->ki", w, p) / w.sum(axis=1, keepdims=True)
        # rotate about the weighted centre, so that rotation and translation decouple
        jac = np.concatenate([np.cross(p - centre[:, None], normal), normal], axis=2)   # d r / d(omega, dt)
        weighted = jac * w[..., None]
        a = np.einsum("kni,knj->kij", weighted, jac)
        b = np.einsum("kni,kn->ki", weighted, np.where(w > 0, r, 0.0))
        damping = DAMPING * np.trace(a, axis1=1, axis2=2)[:, None, None] * np.eye(6)
        step = -np.linalg.solve(a + damping, b[..., None])[..., 0]
        turn = Rotation.from_rotvec(step[:, :3]).as_matrix()
        rotation[active] = turn @ rotation[active]
        shift[active] = np.einsum("kij,kj->ki", turn, shift[active] - centre) + centre + step[:, 3:]
        normal_matrix[active] = a
        # Points far beyond the largest kept residual cannot come back into the fit this step;
        # searching only near the surface spares the KD-tree its slowest queries.
        largest = np.max(np.where(w > 0, np.abs(r), 0.0), axis=1)
        bound_m[active] = BOUND_FACTOR * largest + BOUND_SPACINGS * index.spacing_m
        moved = np.linalg.norm(step[:, :3], axis=1) * size_m + np.linalg.norm(step[:, 3:], axis=1)
        active = active[moved >= STEP_TOL * size_m]
        if active.size == 0:
            break
    matrix = np.broadcast_to(np.eye(4), (n_starts, 4, 4)).copy()
    matrix[:, :3, :3], matrix[:, :3, 3] = rotation, shift
    return IcpTrials(matrix, bound_m, normal_matrix, iterations)


def _plane_residuals(p, index, bound_m):
    """Point-to-plane residuals of points ``p`` (N, 3) (inf where no surface is within ``bound_m``)
    and the planes' normals (N, 3)."""
    normal, offset = index.nearest_planes(p, bound_m)
    r = np.einsum("ij,ij->i", normal, p) - offset
    return np.where(np.isfinite(offset), r, np.inf), normal
