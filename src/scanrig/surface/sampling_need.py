"""Where more samples are needed: curvature-limited spacing, density per area, fold spread.

The map is evaluated on a regular grid in each chart's ``(u, v)`` plane (nodes owned by the
chart, i.e. whose nearest input point is one of its own), so it also covers holes in the data.
Three criteria, each a per-node number where larger means "sample here":

``curvature``
    ``h_actual / h_required``: the local sample spacing over the spacing allowed by the chordal
    error ``tolerance`` at the fitted surface's largest principal curvature,
    ``h_required = sqrt(8 tolerance / kappa_max)``.
``density``
    ``median density / density``: inliers per square metre of surface (from the ``k`` nearest
    inliers), relative to the cloud's median.
``spread``
    ``std / tolerance``: standard deviation, over the chart's full and fold networks, of the
    fitted height (the fold networks see disjoint halves of the data: a half-sampling
    bootstrap, our choice; it grows in gaps and at borders).

``need`` is the curvature criterion (it already folds in the density through ``h_actual``);
``need > 1`` marks nodes sampled more coarsely than the tolerance allows. The scan planner
consumes ``positions``, ``normals`` and ``need``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from scanrig.errors import InputError


@dataclass
class SamplingNeedMap:
    """Sampling-need criteria at surface nodes (M nodes).

    Attributes
    ----------
    positions : (M, 3) float array
        Nodes on the fitted surface, metres.
    normals : (M, 3) float array
        Unit surface normals at the nodes (sign: the chart's normal side).
    h_required : (M,) float array
        Largest spacing meeting the chordal tolerance, metres (inf where flat).
    h_actual : (M,) float array
        Local inlier spacing ``1 / sqrt(density)``, metres.
    density : (M,) float array
        Inliers per square metre.
    spread : (M,) float array
        Fold-network standard deviation of the height, metres.
    curvature, density_need, spread_need, need : (M,) float arrays
        The criteria (see the module docstring); larger means sample here.
    """

    positions: np.ndarray
    normals: np.ndarray
    h_required: np.ndarray
    h_actual: np.ndarray
    density: np.ndarray
    spread: np.ndarray
    curvature: np.ndarray
    density_need: np.ndarray
    spread_need: np.ndarray
    need: np.ndarray


def sampling_need(result, *, tolerance: float, step: float | None = None, k: int = 8) -> SamplingNeedMap:
    """Evaluate the sampling-need criteria of a filtered cloud.

    Parameters
    ----------
    result : FilterResult
        Output of :func:`~scanrig.surface.filter.filter_points`.
    tolerance : float
        Chordal (sagitta) error allowed between samples, metres.
    step : float, optional
        Node spacing in metres (default: the median inlier spacing).
    k : int
        Nearest inliers used for the density.

    Returns
    -------
    SamplingNeedMap
    """
    if not tolerance > 0:
        raise InputError(f"tolerance must be > 0 metres, got {tolerance}")
    inliers = result.denoised[result.inlier]
    if len(inliers) < k + 1:
        raise InputError(f"need at least {k + 1} inliers for a sampling-need map, got {len(inliers)}")
    tree = cKDTree(inliers)
    if step is None:
        step = float(np.median(tree.query(inliers, k=2)[0][:, 1]))
    owner_tree = cKDTree(result.denoised)
    owner = np.empty(len(result.denoised), dtype=int)
    for c, chart in enumerate(result.charts):
        owner[chart.core] = c

    uv_nodes, chart_of = [], []
    for c, chart in enumerate(result.charts):
        local = chart.to_chart(result.denoised[chart.core])
        lo, hi = local[:, :2].min(axis=0), local[:, :2].max(axis=0)
        gu, gv = (np.arange(lo[i], hi[i] + step / 2, step) for i in range(2))
        uv = np.stack(np.meshgrid(gu, gv), axis=-1).reshape(-1, 2)
        approx = chart.from_chart(np.column_stack([uv, np.zeros(len(uv))]))
        mine = owner[owner_tree.query(approx)[1]] == c
        uv_nodes.append(uv[mine])
        chart_of.append(np.full(mine.sum(), c))
    m_max = max(len(u) for u in uv_nodes)
    padded = np.zeros((len(result.charts), m_max, 2))
    for c, uv in enumerate(uv_nodes):
        padded[c, :len(uv)] = uv / result.uv_scale[c]
    heights = result.fits.predict(padded, folds=True)  # (C, K + 1, m)
    grad, hess = result.fits.height_derivatives(padded)

    rows = []
    for c, (uv, chart) in enumerate(zip(uv_nodes, result.charts)):
        m = len(uv)
        zs, us = result.z_scale[c], result.uv_scale[c]
        g = grad[c, :m] * zs / us
        h = hess[c, :m] * zs / us**2
        kappa = _max_principal_curvature(g, h)
        pos = chart.from_chart(np.column_stack([uv, heights[c, 0, :m] * zs]))
        n_local = np.column_stack([-g, np.ones(m)]) / np.sqrt(1 + (g**2).sum(axis=1))[:, None]
        rows.append((pos, n_local @ chart.rotation, kappa, heights[c, :, :m].std(axis=0) * zs))
    pos, normals, kappa, spread = (np.concatenate(v) for v in zip(*rows))

    r_k = tree.query(pos, k=k)[0][:, -1]
    density = k / (np.pi * np.maximum(r_k, 1e-300) ** 2)
    h_actual = 1.0 / np.sqrt(density)
    with np.errstate(divide="ignore"):
        h_required = np.sqrt(8.0 * tolerance / kappa)
    curvature = h_actual / h_required
    density_need = np.median(density) / density
    spread_need = spread / tolerance
    return SamplingNeedMap(pos, normals, h_required, h_actual, density, spread, curvature,
                           density_need, spread_need, curvature)


def _max_principal_curvature(grad: np.ndarray, hess: np.ndarray) -> np.ndarray:
    """Largest absolute principal curvature of graphs ``h = f(u, v)``, 1/metre.

    Parameters
    ----------
    grad : (m, 2) float array
        ``(f_u, f_v)``.
    hess : (m, 2, 2) float array
        Second derivatives, 1/metre.
    """
    fu, fv = grad[:, 0], grad[:, 1]
    fuu, fuv, fvv = hess[:, 0, 0], hess[:, 0, 1], hess[:, 1, 1]
    w = 1.0 + fu**2 + fv**2
    gauss = (fuu * fvv - fuv**2) / w**2
    mean = ((1 + fv**2) * fuu - 2 * fu * fv * fuv + (1 + fu**2) * fvv) / (2 * w**1.5)
    root = np.sqrt(np.maximum(mean**2 - gauss, 0.0))
    return np.maximum(np.abs(mean + root), np.abs(mean - root))
