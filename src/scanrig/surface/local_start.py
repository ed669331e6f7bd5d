"""High-breakdown start of the robust fit: least trimmed squares planes through neighbourhoods.

A redescending loss must start near a good fit (reference notes section 1.4: "starting with a
nonrobust estimate will often lead to the wrong local optimum"). The start must also know the
noise scale, or its cut-offs admit the outliers. Both come from small local fits here (our
choice, after the first stage of Sinha & Schunck's two-stage robust surface reconstruction):

1. every point's ``k`` nearest neighbours (the point itself left out) get a plane
   ``h = c0 + c1 du + c2 dv`` by least trimmed squares on the half of them with the smallest
   residuals (concentration steps from the neighbours' median; breakdown point 1/2 locally, so
   the start survives a global bad fraction up to ``q`` <= 1/2 wherever the bad points are not
   clustered);
2. the point's *held-out* residual is its height minus that plane at the point, and the plane's
   own scale (trimmed, made consistent for Gaussian residuals) says whether the neighbourhood is
   a surface at all: inside a cluster of outliers (a patch of secondary reflections, all of it
   bad) the kept half is spread over the cluster's height range, far wider than the noise;
3. the noise scale of the chart is the robust scale (breakdown point ``q``, bootstrap upper
   bound) of the held-out residuals of the points whose neighbourhood is a surface (at the
   scale of every residual, without its bound): inside a cluster the held-out residuals spread
   over its height range and some fall in the noise band, which inflated the scale (simulated
   scan at 40 %, held-out seed 101: 1.44 sigma from every residual, 1.12 from those of surface
   neighbourhoods, the true inliers' alone 1.12); a point starts as good when its residual is
   within the Hampel rejection point and its neighbourhood is a surface.

The network's first epochs train on the good points and, in place of every other point, on the
chart's least-squares quadratic through the good points (:func:`fill_with_quadratic`): a network
trained on the good points alone extrapolates freely into the holes the start leaves (clusters,
edges), and where a hole reaches the chart's border it can start many noise scales away from the
true points there, which the redescending loss then never takes back.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from scanrig.surface.hampel import refined_scale, robust_scale, trimmed_consistency

#: Neighbourhood scale above this multiple of the chart's noise scale: not a surface (a cluster).
SURFACE_SCALE_FACTOR = 2.5
#: Fewest points of surface neighbourhoods that estimate a chart's noise scale on their own.
MIN_SURFACE_POINTS = 20


def local_trimmed_planes(uv: np.ndarray, z: np.ndarray, *, k: int = 24, keep: float = 0.5,
                         steps: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Held-out residual and trimmed scale of a least-trimmed-squares plane per neighbourhood.

    Parameters
    ----------
    uv, z, k, keep, steps
        As in :func:`neighbour_planes`.

    Returns
    -------
    residual : (m,) float array
        ``z`` minus the plane of the point's neighbours at the point.
    scale : (m,) float array
        As in :func:`neighbour_planes`.
    """
    _, coef, scale = neighbour_planes(uv, z, k=k, keep=keep, steps=steps)
    return z - coef[:, 0], scale


def neighbour_planes(uv: np.ndarray, z: np.ndarray, *, k: int, keep: float = 0.5,
                     steps: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-trimmed-squares plane of every point's ``k`` nearest neighbours (itself left out).

    Parameters
    ----------
    uv : (m, 2) float array
        Chart coordinates.
    z : (m,) float array
        Heights.
    k : int
        Neighbours, clipped to ``[3, m - 1]``.
    keep, steps
        As in :func:`trimmed_planes`.

    Returns
    -------
    neighbours : (m, k) int array
        Each point's neighbours, nearest first.
    planes : (m, 3) float array
        ``(height at the point, slope along u, slope along v)``.
    scale : (m,) float array
        Scale of the kept half of the neighbours' residuals (Gaussian-consistent).
    """
    k = max(3, min(k, len(z) - 1))
    _, idx = cKDTree(uv).query(uv, k=k + 1)
    nb = idx[:, 1:]
    planes, scale = trimmed_planes(uv[nb] - uv[:, None, :], z[nb], keep=keep, steps=steps)
    return nb, planes, scale


def trimmed_planes(du: np.ndarray, zn: np.ndarray, *, keep: float = 0.5,
                   steps: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Least-trimmed-squares planes ``h = c0 + c1 du + c2 dv`` of many small point sets at once.

    Concentration steps from the sets' median heights: each step refits by least squares the
    ``ceil(keep * k)`` points of smallest absolute residual (breakdown point ``1 - keep``).

    Parameters
    ----------
    du : (m, k, 2) float array
        In-plane offsets of each set's points from the point where ``c0`` is wanted.
    zn : (m, k) float array
        Their heights.
    keep : float
        Fraction of each set kept.
    steps : int
        Concentration steps.

    Returns
    -------
    coef : (m, 3) float array
        ``(c0, c1, c2)``: height at zero offset and slopes.
    scale : (m,) float array
        Scale of the kept residuals (Gaussian-consistent).
    """
    m, k = zn.shape
    h = min(k, max(4, int(np.ceil(keep * k))))
    # the kept points' sums of 1, du, dv, du^2, du dv, dv^2, z, du z, dv z as masked sums of
    # products formed once: no gather of the kept points (which took 3x as long for 200 000 sets)
    u, v = du[..., 0], du[..., 1]
    products = np.stack([np.ones_like(zn), u, v, u * u, u * v, v * v, zn, u * zn, v * zn], axis=1)  # (m, 9, k)
    pairs = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])

    def squared_residuals(coef):
        return np.square(zn - coef[:, :1] - coef[:, 1:2] * u - coef[:, 2:] * v)

    coef = np.zeros((m, 3))
    coef[:, 0] = np.median(zn, axis=1)
    for _ in range(steps):
        r2 = squared_residuals(coef)
        kept = r2 <= np.partition(r2, h - 1, axis=1)[:, h - 1:h]  # ties keep a few more
        sums = np.matmul(products, kept[..., None].astype(float))[..., 0]  # 3x faster than einsum
        gram = sums[:, pairs] + 1e-9 * (sums[:, 0] + sums[:, 3] + sums[:, 5])[:, None, None] * np.eye(3)
        coef = np.linalg.solve(gram, sums[:, 6:, None])[..., 0]
    r2 = np.partition(squared_residuals(coef), h - 1, axis=1)[:, :h]
    q_local = 1.0 - h / k
    scale = np.sqrt(r2.mean(axis=1) / (trimmed_consistency(min(max(q_local, 1e-3), 0.5)) * (1.0 - 3.0 / h)))
    return coef, scale


def robust_start(uv: np.ndarray, z: np.ndarray, valid: np.ndarray, *, q: float, cut: float,
                 rng: np.random.Generator, k: int = 24, scale_cut: float = 2.5, n_boot: int = 200,
                 alpha: float = 0.05, sigma_floor: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Starting weights (0/1) and noise-scale upper bound of every chart.

    Parameters
    ----------
    uv : (C, n_max, 2) float array
    z : (C, n_max) float array
    valid : (C, n_max) bool array
    q : float
        Tolerated bad fraction (breakdown point of the chart's scale).
    cut : float
        Rejection point in units of the scale (Hampel ``r``).
    rng : numpy.random.Generator
        Bootstrap of the scale.
    k : int
        Neighbours of the local planes.
    scale_cut, n_boot, alpha
        Truncation of the scale's refinement, bootstrap resamples and level of its upper bound
        (:func:`~scanrig.surface.hampel.robust_scale`).
    sigma_floor : float or (C,) float array
        Lower bound of each chart's noise scale (the known noise of its points). Neighbours
        along one laser stripe share most of their error, so their planes predict each point
        far closer than the noise, and without it the start rejects the points where stripes
        cross.

    Returns
    -------
    good : (C, n_max) bool array
        Points that start as good.
    sigma_upper : (C,) float array
        Bootstrap upper bound of each chart's noise scale from the held-out residuals of the
        surface neighbourhoods (of all points if fewer than ``MIN_SURFACE_POINTS`` are), at
        least ``sigma_floor``.
    """
    good = np.zeros(valid.shape, dtype=bool)
    sigma_upper = np.empty(len(valid))
    floor = np.broadcast_to(np.asarray(sigma_floor, dtype=float), sigma_upper.shape)
    for c in range(len(valid)):
        m = int(valid[c].sum())
        residual, scale = local_trimmed_planes(uv[c, :m], z[c, :m], k=k)
        sigma_all = max(refined_scale(residual, q, cut=scale_cut)[0], floor[c])
        surface = scale <= SURFACE_SCALE_FACTOR * sigma_all
        if surface.sum() < MIN_SURFACE_POINTS:
            surface[:] = True
        _, sigma_upper[c] = robust_scale(residual[surface], q, rng=rng, cut=scale_cut, n_boot=n_boot,
                                        alpha=alpha)
        sigma_upper[c] = max(sigma_upper[c], floor[c])
        good[c, :m] = (np.abs(residual) <= cut * sigma_upper[c]) & (scale <= SURFACE_SCALE_FACTOR * sigma_upper[c])
    return good, sigma_upper


def quadratic_basis(uv: np.ndarray) -> np.ndarray:
    """The terms ``1, u, v, u^2, u v, v^2`` of a quadratic height field at ``uv`` (..., 2): (..., 6)."""
    u, v = uv[..., 0], uv[..., 1]
    return np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)


def fill_with_quadratic(uv: np.ndarray, z: np.ndarray, valid: np.ndarray, good: np.ndarray) -> np.ndarray:
    """Heights of the good points, and the chart's quadratic through them at every other point.

    The quadratic ``h = c0 + c1 u + c2 v + c3 u^2 + c4 u v + c5 v^2`` is each chart's least-squares
    fit to its good points; it fills the holes of the start with the smoothest plausible surface
    (measured over the 24 protocol cells and three weight seeds: mean robust error 1.021 times
    the oracle's instead of 1.037; sphere cap at 40 % outliers at worst 1.06 instead of 1.47,
    saddle 1.06 instead of 1.54).

    Parameters
    ----------
    uv : (C, n, 2) float array
        Normalised chart coordinates.
    z : (C, n) float array
    valid, good : (C, n) bool arrays
        Real points; points the start trusts.

    Returns
    -------
    (C, n) float array
        ``z`` where ``good``, the quadratic elsewhere (padding included).
    """
    basis = quadratic_basis(uv)  # (C, n, 6)
    w = (good & valid).astype(float)
    gram = np.einsum("cni,cn,cnj->cij", basis, w, basis)
    rhs = np.einsum("cni,cn,cn->ci", basis, w, z)
    # the pseudo-inverse: a chart with fewer than six good points, or all of them on a line, gets
    # the least-squares quadratic of smallest norm instead of a singular system
    coef = (np.linalg.pinv(gram, hermitian=True) @ rhs[..., None])[..., 0]
    return np.where(good & valid, z, np.einsum("cni,ci->cn", basis, coef))
