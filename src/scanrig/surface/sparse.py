"""Judge the points of sparse charts by local robust quadrics instead of their chart's network.

A chart with few points (a sparse cloud: a spot scan, a few thousand points over a whole part)
has too few of them for its network: the fold networks, trained on half of a chart of 50-300
points, extrapolate loosely, their held-out residuals are several times the noise, and the
network's judgement condemns good points and keeps outliers. On 1,500 points of a capsule of
radius 60 mm, ~8 mm apart, 20 um noise and 10 % outliers 0.4-5 mm off, the networks kept 87 % of
the good points and rejected 90 % of the outliers.

Here such a point is judged by a fit of lower order and of its own support: a least trimmed
squares fit through its nearest neighbours in 3-D (the point itself left out), in the frame of
the neighbours' principal axes (``x, y`` across, ``z`` along their normal), with Gaussian
weights over the neighbours' distances (width: their median distance) so that the fit is local
where the surface curves. Two models are fitted:

* the quadratic height field ``z = q(x, y)`` (6 terms) through ``LOCAL_NEIGHBOURS`` neighbours;
* the quadric ``z = q(x, y) + a xz + b yz + c z^2`` (9 terms, every quadric whose normal at the
  point is not across the frame's ``z``) through ``QUADRIC_NEIGHBOURS`` neighbours. A sphere or
  a cylinder is one exactly, whatever angle the neighbours span, where the height field's error
  grows as the fourth power of that angle: 15 mm apart on a 30 mm cylinder (12 points around it)
  the neighbours of a quadratic span most of a half-turn, its misfit was 11 noise sigmas (median
  over the good points) and it rejected 69 % of the outliers.

The point takes the quadric's judgement where the quadric's local misfit (below) is less than
``1 / QUADRIC_PREFERENCE`` of the quadratic's, else the quadratic's: where both follow the
surface, the one with fewer terms and neighbours (a quadric through more outliers than its
trimming tolerates, or across a curvature seam, errs more often).

Each fit starts from the best of ``LOCAL_TRIALS`` elemental fits (as many neighbours as terms)
by the sum of the smallest ``h`` squared residuals (``h = (k + p + 1) / 2 + 1`` for ``p`` terms,
the LTS optimum), then takes concentration steps (as in FAST-LTS). The point's residual is the
fit's height at the point over the length of the fit's gradient there (the distance to its
tangent plane). The point's score is that residual over the larger of

* the reference noise times ``sqrt(1 + g)``, ``g`` the fit's prediction variance at the point
  in units of the noise variance (the noise the caller knows, or learnt where the data are dense);
* the local misfit: the scaled median of the kept neighbours' leave-one-out residuals, which
  holds what the fit cannot follow (a curvature seam, a surface curving faster than the
  sampling) besides the noise.

A point is an inlier when its score is at most ``r``, as for the networks.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from scanrig.geometry.uncertainty import MAD_TO_SIGMA
from scanrig.surface.charts import frames_from_normals
from scanrig.surface.local_start import quadratic_basis

#: A chart with fewer members than this is judged by :func:`local_quadratic_scores`. The
#: protocol's dense charts (32 x 32 grids and up) have at least 480 members, a sparse cloud's
#: 60-320 (1,000-2,000 points on a capsule, 5-15 mm apart).
SPARSE_CHART_POINTS = 400
#: Neighbours of each local quadratic (16: 91-94 % of the outliers rejected on the capsules at
#: 20 % outliers, 20: 96-99 %, 24: good points kept 97-98 % where the surface curves fastest).
LOCAL_NEIGHBOURS = 20
#: Neighbours of each local quadric: its trimming tolerates ``(k - 9) / 2`` outliers. Alone on
#: the capsules at 20 % outliers, 20 neighbours rejected 70-83 % of the outliers, 26 and
#: 32 95-99.5 % (seeds 0-2); 32 kept more of the good points where the quadric is chosen.
QUADRIC_NEIGHBOURS = 32
#: The quadric judges a point where its misfit is below the quadratic's over this factor. On the
#: sparse capsules, medians over seeds 0-2: with 1 the 2000-point capsule of radius 100 mm kept
#: 98.3 % of its good points; with 2 and 3, 98.9-99.9 % on every capsule.
QUADRIC_PREFERENCE = 2.0
#: Elemental fits tried per neighbourhood for the start. A quadric's nine-point subset is clean
#: with probability 0.068 among 20 neighbours of which 4 are outliers: 96 trials miss every
#: clean one with probability 0.001.
LOCAL_TRIALS = 96
#: Concentration steps after the start.
LOCAL_STEPS = 6
#: A point off its quadratic is condemned only when the fit kept at least ``SUPPORT_POINTS``
#: neighbours within ``SUPPORT_RADIUS`` times the point's distance to its ``SUPPORT_NEAREST``-th
#: neighbour, and within ``SUPPORT_SPACINGS`` typical spacings (the judged points' median distance
#: to their nearest neighbour): a surface that does not pass near the point cannot condemn it.
#: The spot demo's cloud is clusters of ~6 spots 10 mm apart, ~100 mm from the next cluster; the
#: quadratic through a ball cluster's 20 nearest points is the floor's, 50-70 mm below it, and
#: flagged all six. A lone spot on the block's upper step, 52 mm (5.2 spacings) from any other,
#: was flagged on 1-9 of 10 seeds with 6-8 spacings, on none with 4-5; on the capsules 5 spacings
#: flag the same outliers as no limit, 4 spacings 3 % fewer where they are 15 mm apart.
SUPPORT_NEAREST = 5
SUPPORT_RADIUS = 2.5
SUPPORT_SPACINGS = 5.0
SUPPORT_POINTS = 4
#: Points per vectorised block (bounds the memory: block x trials x neighbours x 9 floats, 0.1 GB).
BLOCK_POINTS = 512


def local_quadratic_scores(points: np.ndarray, normals: np.ndarray, judged: np.ndarray, *,
                           rng: np.random.Generator, k: int = LOCAL_NEIGHBOURS,
                           k_quadric: int = QUADRIC_NEIGHBOURS
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Held-out residuals of local robust quadratics or quadrics at the ``judged`` points.

    Each point takes the judgement of its quadric where the quadric's misfit is below the
    quadratic's over ``QUADRIC_PREFERENCE``, else of its quadratic (see the module).

    Parameters
    ----------
    points : (N, 3) float array
        The cloud, metres.
    normals : (N, 3) float array
        Unit normals; orient each local frame (the sign of ``residual``).
    judged : (m,) int array
        Points to judge; their neighbours are taken among all points.
    rng : numpy.random.Generator
        Draws the elemental subsets.
    k, k_quadric : int
        Neighbours of each quadratic and of each quadric, clipped to ``N - 1`` (a robust fit needs
        at least 10 and 16).

    Returns
    -------
    residual : (m,) float array
        Signed distance of each judged point from the tangent plane of its neighbours' fit,
        along the local normal, metres.
    g : (m,) float array
        Prediction variance of the fit's height at the point, in units of the noise variance.
    misfit : (m,) float array
        Scaled median absolute leave-one-out residual of the kept neighbours, metres.
    support : (m,) int array
        Neighbours the fit kept within ``SUPPORT_RADIUS`` times the point's distance to its
        ``SUPPORT_NEAREST``-th neighbour, that distance at most ``SUPPORT_SPACINGS`` typical
        spacings (the judged points' median distance to their nearest neighbour).
    """
    judged = np.asarray(judged, dtype=int)
    k, k_quadric = min(k, len(points) - 1), min(k_quadric, len(points) - 1)
    residual, g, misfit = (np.empty(len(judged)) for _ in range(3))
    support = np.zeros(len(judged), int)
    if len(judged) == 0:
        return residual, g, misfit, support
    dist, nb = cKDTree(points).query(points[judged], k=max(k, k_quadric) + 1)
    dist, nb = dist[:, 1:], nb[:, 1:]  # the point itself is its own nearest
    reach = SUPPORT_SPACINGS * np.median(dist[:, 0])
    for start in range(0, len(judged), BLOCK_POINTS):
        sl = slice(start, start + BLOCK_POINTS)
        quadratic = _local_fit(points, normals, judged[sl], nb[sl, :k], dist[sl, :k], reach, rng,
                               lambda xyz: quadratic_basis(xyz[..., :2]))
        quadric = _local_fit(points, normals, judged[sl], nb[sl, :k_quadric], dist[sl, :k_quadric], reach, rng,
                             quadric_basis)
        pick = QUADRIC_PREFERENCE * quadric[2] < quadratic[2]
        residual[sl], g[sl], misfit[sl], support[sl] = (np.where(pick, b, a) for a, b in zip(quadratic, quadric))
    return residual, g, misfit, support


def quadric_basis(xyz: np.ndarray) -> np.ndarray:
    """The terms ``1, x, y, x^2, x y, y^2, x z, y z, z^2`` of a local quadric ``z = c . terms`` at
    ``xyz`` (..., 3): (..., 9). With ``z`` on both sides it holds every quadric whose normal at
    the origin is not across ``z``; the first six terms are :func:`quadratic_basis`'s."""
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    return np.concatenate([quadratic_basis(xyz[..., :2]), np.stack([x * z, y * z, z * z], axis=-1)], axis=-1)


def _local_fit(points: np.ndarray, normals: np.ndarray, judged: np.ndarray, nb: np.ndarray, dist: np.ndarray,
               reach: float, rng: np.random.Generator, basis_of
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Residual, g, misfit and support (each (m,)) of the ``judged`` points (m,) against the trimmed
    fits of ``basis_of`` (local xyz (m, k, 3) -> terms (m, k, p)) through their neighbours ``nb``
    (m, k) at distances ``dist`` (m, k); see :func:`local_quadratic_scores`."""
    offsets = points[nb] - points[judged, None, :]
    axes = frames_from_normals(_principal_normal(offsets, normals[judged]))
    size = np.maximum(np.median(dist, axis=1), 1e-300)  # (m,) metres per unit of the fit
    # in units of the neighbours' median distance: in metres, a quadric's products of three
    # coordinates span 1e-6 of its constant term and its elemental solves lost the fit (a clean
    # cylinder 15 mm apart missed by up to 490 um)
    local = np.einsum("mki,mij->mkj", offsets, axes) / size[:, None, None]
    weight = np.exp(-np.square(dist / size[:, None]))
    coef, g, misfit, kept = _trimmed_fits(basis_of(local), local[..., 2], weight, rng)
    # the point at the origin, height 0: its distance to the fit's tangent plane there
    residual = -coef[:, 0] * size / np.hypot(1.0, np.hypot(coef[:, 1], coef[:, 2]))
    near = dist <= np.minimum(SUPPORT_RADIUS * dist[:, SUPPORT_NEAREST - 1:SUPPORT_NEAREST], reach)
    return residual, g, misfit * size, np.count_nonzero(kept & near, axis=1)


def _principal_normal(offsets: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Unit normal (m, 3) of each neighbourhood (m, k, 3): its smallest principal axis, turned to
    agree with the point's normal (m, 3)."""
    centred = offsets - offsets.mean(axis=1, keepdims=True)
    axis = np.linalg.eigh(np.einsum("mki,mkj->mij", centred, centred))[1][..., 0]
    return axis * np.where(np.einsum("mi,mi->m", axis, normals) < 0, -1.0, 1.0)[:, None]


def _trimmed_fits(basis: np.ndarray, h: np.ndarray, weight: np.ndarray, rng: np.random.Generator
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Weighted least-trimmed-squares fits ``h = basis . coef`` of many neighbourhoods at once.

    Parameters
    ----------
    basis : (m, k, p) float array
        Terms of the model at the neighbours (:func:`quadratic_basis` or :func:`quadric_basis` of
        their local offsets); the first three are ``1, x, y``.
    h : (m, k) float array
        Heights, in the units of the offsets.
    weight : (m, k) float array
        Distance weights of the neighbours.
    rng : numpy.random.Generator

    Returns
    -------
    coef : (m, p) float array
        Coefficients of the terms; ``coef[:, 0]`` is the height at the origin.
    g : (m,) float array
        Variance of ``coef[:, 0]`` over the noise variance.
    misfit : (m,) float array
        Scaled median absolute leave-one-out residual of the kept neighbours, units of ``h``.
    kept : (m, k) bool array
        The neighbours of the last concentration step.
    """
    m, k, p = basis.shape
    h_keep = min(k, (k + p + 1) // 2 + 1)
    subsets = np.argsort(rng.random((m, LOCAL_TRIALS, k)), axis=2)[..., :p]
    sub_basis = np.take_along_axis(basis[:, None], subsets[..., None], axis=2)  # (m, T, p, p)
    sub_h = np.take_along_axis(np.broadcast_to(h[:, None], (m, LOCAL_TRIALS, k)), subsets, axis=2)
    scale = np.einsum("mki,mki->m", basis, basis)[:, None, None, None] / k  # a ridge for degenerate subsets
    trial = np.linalg.solve(sub_basis.transpose(0, 1, 3, 2) @ sub_basis + 1e-12 * scale * np.eye(p),
                            (sub_basis.transpose(0, 1, 3, 2) @ sub_h[..., None]))[..., 0]
    r2 = np.square(h[:, None] - np.einsum("mki,mti->mtk", basis, trial))
    objective = np.partition(r2, h_keep - 1, axis=2)[..., :h_keep].sum(axis=2)
    coef = trial[np.arange(m), np.argmin(objective, axis=1)]
    ridge = 1e-12 * np.einsum("mki,mki->m", basis, basis)[:, None, None] * np.eye(p)
    for _ in range(LOCAL_STEPS):
        r2 = np.square(h - np.einsum("mki,mi->mk", basis, coef))
        kept = r2 <= np.partition(r2, h_keep - 1, axis=1)[:, h_keep - 1:h_keep]
        w = kept * weight
        gram = np.einsum("mki,mk,mkj->mij", basis, w, basis) + ridge
        coef = np.linalg.solve(gram, np.einsum("mki,mk,mk->mi", basis, w, h)[..., None])[..., 0]
    inverse = np.linalg.inv(gram)
    # weighted least squares: Var(c0) = e0^T G^-1 (B^T W^2 B) G^-1 e0 sigma^2
    g = np.einsum("mi,mij,mj->m", inverse[:, 0], np.einsum("mki,mk,mkj->mij", basis, w * w, basis), inverse[:, 0])
    leverage = np.einsum("mki,mij,mkj->mk", basis, inverse, basis) * w
    loo = np.abs(h - np.einsum("mki,mi->mk", basis, coef)) / np.clip(1.0 - leverage, 0.05, None)
    misfit = MAD_TO_SIGMA * np.nanmedian(np.where(kept, loo, np.nan), axis=1)
    return coef, g, misfit, kept
