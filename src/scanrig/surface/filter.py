"""The whole-cloud robust filter: charts, robust network fits, blending, per-point outputs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError, ShapeError
from scanrig.geometry.checks import check_points
from scanrig.surface.charts import Chart, blend_weights, estimate_normals, split_charts
from scanrig.surface.hampel import check_q
from scanrig.surface.robust_fit import ChartFits, FitSettings, fit_charts

MIN_POINTS = 16  # below this a surface network (2 folds x several points) is meaningless


@dataclass
class FilterResult:
    """Per-point outputs of :func:`filter_points` and the fitted charts.

    Attributes
    ----------
    denoised : (N, 3) float array
        Each input point projected on the fitted surface along its chart normal, metres;
        blended over overlapping charts.
    inlier : (N,) bool array
        ``score <= r`` (the Hampel rejection point): the point lies inside the good-data band.
    score : (N,) float array
        Robust score ``|held-out residual| / sigma+`` (sigma+ the bootstrap upper bound of the
        chart's noise scale); dimensionless, larger is more suspicious.
    residual : (N,) float array
        Signed distance from the fitted surface along the chart normal, metres.
    sigma : (N,) float array
        Noise scale sigma+ of the point's charts, metres.
    charts : list of Chart
    fits : ChartFits
        Networks in the charts' normalised units (see ``uv_scale`` and ``z_scale``).
    uv_scale, z_scale : (C,) float arrays
        Metres per normalised unit of each chart's ``(u, v)`` and height.
    settings : FitSettings
    """

    denoised: np.ndarray
    inlier: np.ndarray
    score: np.ndarray
    residual: np.ndarray
    sigma: np.ndarray
    charts: list[Chart]
    fits: ChartFits
    uv_scale: np.ndarray
    z_scale: np.ndarray
    settings: FitSettings


def filter_points(points: np.ndarray, *, rng: np.random.Generator, q: float = 0.25,
                  settings: FitSettings | None = None, max_chart_points: int = 4096,
                  sigma_floor: float = 0.0, device: str = "cpu",
                  train_mask: np.ndarray | None = None) -> FilterResult:
    """Robustly fit a surface to a point cloud, flag bad points and denoise the good ones.

    Parameters
    ----------
    points : (N, 3) float array
        Measured points, metres. Any closed or open surface: it is split into height-field
        charts (:func:`~scanrig.surface.charts.split_charts`).
    rng : numpy.random.Generator
        Seeds network weights, folds and bootstraps.
    q : float
        Tolerated fraction of bad data, in (0, 0.5]; overrides ``settings.q``.
    settings : FitSettings, optional
        Network, loss and schedule (defaults of :class:`FitSettings`).
    max_chart_points : int
        Largest number of points a chart owns.
    sigma_floor : float
        Known sensor noise in metres: the noise scale is never taken below it.
    device : str
        Torch device: ``"cpu"``, ``"cuda"``, or ``"auto"`` (CUDA when present).
    train_mask : (N,) bool array, optional
        Only these points train the networks (the benchmark's oracle); all are evaluated.

    Returns
    -------
    FilterResult

    Raises
    ------
    InputError
        Empty or too small cloud, non-finite coordinates, ``q`` outside (0, 0.5], too small
        ``max_chart_points``.
    """
    points = check_points(points, 3, "points")
    if len(points) < MIN_POINTS:
        raise InputError(f"points must hold at least {MIN_POINTS} points to fit a surface, got {len(points)}")
    if not np.all(np.isfinite(points)):
        bad = int(np.count_nonzero(~np.isfinite(points).all(axis=1)))
        raise InputError(f"points must be finite: {bad} rows hold NaN or infinite coordinates")
    q = check_q(q)
    if max_chart_points < MIN_POINTS:
        raise InputError(f"max_chart_points must be >= {MIN_POINTS}, got {max_chart_points}")
    settings = FitSettings(**{**(settings or FitSettings()).__dict__, "q": q})
    if train_mask is not None:
        train_mask = np.asarray(train_mask, dtype=bool)
        if train_mask.shape != (len(points),):
            raise ShapeError(f"train_mask must have shape ({len(points)},), got {train_mask.shape}")
    device = _resolve_device(device)

    charts = split_charts(points, estimate_normals(points), max_points=max_chart_points, q=q)
    n_max = max(len(c.members) for c in charts)
    n_charts = len(charts)
    uv = np.zeros((n_charts, n_max, 2))
    z = np.zeros((n_charts, n_max))
    valid = np.zeros((n_charts, n_max), dtype=bool)
    mask = np.zeros((n_charts, n_max), dtype=bool)
    uv_scale = np.empty(n_charts)
    z_scale = np.empty(n_charts)
    for c, chart in enumerate(charts):
        local = chart.to_chart(points[chart.members])
        m = len(chart.members)
        uv_scale[c] = max(chart.radius, 1e-300)
        z_scale[c] = max(local[:, 2].std(), 1e-9 * uv_scale[c])
        uv[c, :m] = local[:, :2] / uv_scale[c]
        z[c, :m] = local[:, 2] / z_scale[c]
        valid[c, :m] = True
        mask[c, :m] = True if train_mask is None else train_mask[chart.members]

    fits = fit_charts(uv, z, valid, settings=settings, rng=rng,
                      train_mask=None if train_mask is None else mask,
                      sigma_floor=sigma_floor / z_scale, device=device)

    n = len(points)
    acc = np.zeros((n, 7))  # weight, denoised xyz, residual, score, sigma
    for c, chart in enumerate(charts):
        m = len(chart.members)
        w = blend_weights(chart, points[chart.members])
        height = fits.z_fit[c, :m] * z_scale[c]
        local = np.column_stack([uv[c, :m] * uv_scale[c], height])
        sigma = fits.b[c] / settings.constants.r * z_scale[c]
        values = np.column_stack([
            chart.from_chart(local),
            (z[c, :m] - fits.z_fit[c, :m]) * z_scale[c],
            np.abs(fits.residual_heldout[c, :m]) * z_scale[c] / sigma,
            np.full(m, sigma),
        ])
        np.add.at(acc, chart.members, np.column_stack([w, w[:, None] * values]))
    weight = acc[:, 0]
    if np.any(weight <= 0):
        raise RuntimeError("internal error: a point is covered by no chart")
    out = acc[:, 1:] / weight[:, None]
    score = out[:, 4]
    return FilterResult(denoised=out[:, :3], inlier=score <= settings.constants.r, score=score,
                        residual=out[:, 3], sigma=out[:, 5], charts=charts, fits=fits,
                        uv_scale=uv_scale, z_scale=z_scale, settings=settings)


def _resolve_device(device: str) -> str:
    """``"auto"`` -> ``"cuda"`` when available else ``"cpu"``; other names are checked by torch."""
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    try:
        torch.device(device)
    except RuntimeError as exc:
        raise InputError(f"device must be 'cpu', 'cuda', 'cuda:N' or 'auto', got {device!r}: {exc}") from None
    return device


def project_on_surface(result: FilterResult, points: np.ndarray) -> np.ndarray:
    """Project arbitrary points on the fitted surface along the normals of the charts near them.

    Each chart whose reach (see :func:`~scanrig.surface.charts.blend_weights`) covers a point
    projects it along its normal; the projections are blended with the same partition of unity
    as the input points. A point outside every reach uses the chart with the nearest origin.

    Parameters
    ----------
    result : FilterResult
    points : (m, 3) float array
        Query points near the surface, metres.

    Returns
    -------
    (m, 3) float array
        Points on the fitted surface, metres.
    """
    points = check_points(points, 3, "points")
    weights = np.stack([blend_weights(c, points) for c in result.charts])  # (C, m)
    nearest = np.argmin(np.stack([np.linalg.norm(points - c.origin, axis=1) for c in result.charts]), axis=0)
    uncovered = weights.sum(axis=0) <= 0
    weights[nearest[uncovered], np.flatnonzero(uncovered)] = 1.0
    local = np.stack([c.to_chart(points) for c in result.charts])  # (C, m, 3)
    heights = result.fits.predict(local[..., :2] / result.uv_scale[:, None, None]) * result.z_scale[:, None]
    local[..., 2] = heights
    projected = np.stack([c.from_chart(local[i]) for i, c in enumerate(result.charts)])
    return np.einsum("cm,cmk->mk", weights, projected) / weights.sum(axis=0)[:, None]
