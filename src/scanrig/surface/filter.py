"""The whole-cloud robust filter: charts, robust network fits, blending, per-point outputs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError, ShapeError
from scanrig.geometry.checks import check_points
from scanrig.surface.charts import (MIN_CHART_POINTS, Chart, blend_weights, estimate_normals, halve_charts,
                                    split_charts)
from scanrig.surface.hampel import check_q
from scanrig.surface.memory import keep_freed_memory
from scanrig.surface.robust_fit import ChartFits, FitSettings, concatenate_fits, fit_charts_by_size
from scanrig.surface.sheets import split_sheets
from scanrig.surface.surroundings import surroundings_score

MIN_POINTS = 16  # below this a surface network (2 folds x several points) is meaningless
#: A chart whose noise scale exceeds this multiple of the reference noise (``sigma_floor``, else
#: the typical chart's, :func:`_typical_noise`) is not trusted: it moves no point, and its
#: points are scored against the reference instead of its own loose fit; one that exceeds it
#: times ``sigma_floor``, else its points' median own sigma, else the typical chart's, is
#: halved (:func:`_loose_charts`). Points of known sigma: see ``POINT_TRUST_FACTOR``.
TRUST_FACTOR = 3.0
#: A chart moves a point whose own sigma is known only if its held-out noise scale is at most
#: this multiple of that sigma. The held-out scale is ``sqrt(sigma_point^2 + s_fold^2)`` with
#: ``s_fold`` the error of a fold network's prediction; the full network, trained on twice the
#: points, errs by about ``s_fold / sqrt(2)``, and replacing the point by the fit helps only if
#: that is below ``sigma_point``: ``sqrt(3)``. With ``TRUST_FACTOR`` (3) instead, a 62-point
#: demo cloud of one chart (held-out scale 0.30 mm, median point sigma 0.09 mm) moved a point from
#: 0.13 mm to 0.39 mm off the true surface.
POINT_TRUST_FACTOR = float(np.sqrt(3.0))
#: Rounds of halving the charts that cannot follow their surface (see :func:`_loose_charts`).
REFINE_ROUNDS = 6
#: Largest angle between a point's normal and the normal of a chart that may move it.
MAX_NORMAL_ANGLE = np.deg2rad(60.0)


@dataclass
class FilterResult:
    """Per-point outputs of :func:`filter_points` and the fitted charts.

    Attributes
    ----------
    denoised : (N, 3) float array
        Each input point projected on the fitted surface along its chart normal, metres;
        blended over the overlapping charts allowed to move it (trusted charts whose normal
        agrees with the point's and whose fit the point lies within, see
        :func:`_blend_outputs`); a point no such chart covers keeps its measured position.
    inlier : (N,) bool array
        ``score <= r`` (the Hampel rejection point): the point lies inside the good-data band.
    score : (N,) float array
        Robust score ``|held-out residual| / sigma+`` (sigma+ the bootstrap upper bound of the
        chart's noise scale; for a chart that is not trusted, see ``TRUST_FACTOR``, the
        reference noise instead, and at least the point's score against the trusted surface
        around it, see :func:`_blend_outputs`); dimensionless, larger is more suspicious.
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
                  train_mask: np.ndarray | None = None,
                  point_sigma: np.ndarray | None = None) -> FilterResult:
    """Robustly fit a surface to a point cloud, flag bad points and denoise the good ones.

    Parameters
    ----------
    points : (N, 3) float array
        Measured points, metres. Any closed or open surface: it is split into height-field
        charts (:func:`~scanrig.surface.charts.split_charts`), and a chart holding a step into
        its sheets (:func:`~scanrig.surface.sheets.split_sheets`).
    rng : numpy.random.Generator
        Seeds network weights, folds and bootstraps.
    q : float
        Tolerated fraction of bad data, in (0, 0.5]; overrides ``settings.q``.
    settings : FitSettings, optional
        Network, loss and schedule (defaults of :class:`FitSettings`).
    max_chart_points : int
        Largest number of points a chart owns.
    sigma_floor : float
        Known sensor noise in metres: the noise scale is never taken below it, and a chart
        whose noise scale exceeds ``TRUST_FACTOR`` times it does not move points (default 0:
        the typical chart's noise scale is that reference).
    device : str
        Torch device: ``"cpu"``, ``"cuda"``, or ``"auto"`` (CUDA when present).
    train_mask : (N,) bool array, optional
        Only these points train the networks (the benchmark's oracle), in place of the sheets'
        own choice (:attr:`~scanrig.surface.charts.Chart.trained`); all are evaluated. The
        refinement stops before a round that would leave a half chart fewer than
        ``2 * n_folds`` of them.
    point_sigma : (N,) float array, optional
        Each point's own predicted standard deviation, metres (``sigma`` of ``points.ply``): an
        absolute reference for ``denoised``. A chart moves a point only if its noise scale is
        at most ``POINT_TRUST_FACTOR`` times the point's sigma and the point lies within
        ``r * point_sigma`` of the fit, so no point moves by more than that; without it the
        reference is relative (the typical chart), which a cloud of one chart cannot use.

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
    if point_sigma is not None:
        point_sigma = np.asarray(point_sigma, dtype=float)
        if point_sigma.shape != (len(points),):
            raise ShapeError(f"point_sigma must have shape ({len(points)},), got {point_sigma.shape}")
        if not np.all(np.isfinite(point_sigma) & (point_sigma > 0)):
            raise InputError("point_sigma must be finite and positive")
    device = _resolve_device(device)
    keep_freed_memory()

    normals = estimate_normals(points)
    r = settings.constants.r
    charts = split_sheets(points, normals, split_charts(points, normals, max_points=max_chart_points, q=q),
                          q=q, cut=r, point_sigma=point_sigma)
    fits, uv_scale, z_scale = _fit(points, charts, settings, rng, train_mask, sigma_floor, device, point_sigma)
    for _ in range(REFINE_ROUNDS):
        # a chart that cannot follow its surface (a side of a step too small to be a sheet, a
        # network that failed) is halved and refitted
        loose = _loose_charts(charts, fits, z_scale, settings, sigma_floor, point_sigma)
        loose &= np.array([len(c.core) >= 2 * MIN_CHART_POINTS for c in charts])
        if not loose.any():
            break
        halves = split_sheets(points, normals,
                              halve_charts(points, normals, [c for c, bad in zip(charts, loose) if bad], q=q),
                              q=q, cut=r, point_sigma=point_sigma)
        if train_mask is not None and min(train_mask[h.members].sum() for h in halves) < 2 * settings.n_folds:
            break  # a half of points left out of training has nothing to fit: keep the charts
        new_fits, new_uv_scale, new_z_scale = _fit(points, halves, settings, rng, train_mask, sigma_floor, device,
                                                   point_sigma)
        keep = np.flatnonzero(~loose)
        fits = concatenate_fits([fits, new_fits], np.concatenate([keep, len(charts) + np.arange(len(halves))]))
        charts = [charts[i] for i in keep] + halves
        uv_scale = np.concatenate([uv_scale[keep], new_uv_scale])
        z_scale = np.concatenate([z_scale[keep], new_z_scale])

    return _blend_outputs(points, normals, charts, fits, uv_scale, z_scale, settings, sigma_floor,
                          point_sigma)


def _fit(points: np.ndarray, charts: list[Chart], settings: FitSettings, rng: np.random.Generator,
         train_mask: np.ndarray | None, sigma_floor: float, device: str,
         point_sigma: np.ndarray | None) -> tuple[ChartFits, np.ndarray, np.ndarray]:
    """Fit the charts' networks in normalised coordinates; returns fits, uv and height scales (C,).

    A chart's noise scale is never taken below ``sigma_floor`` nor below the median ``point_sigma``
    of its members: the held-out residuals measure only the noise that neighbours do not share.
    """
    floor = np.full(len(charts), sigma_floor)
    if point_sigma is not None:
        floor = np.maximum(floor, [np.median(point_sigma[chart.members]) for chart in charts])
    uv_scale = np.array([max(chart.radius, 1e-300) for chart in charts])
    local = [chart.to_chart(points[chart.members]) for chart in charts]
    z_scale = np.array([max(h[:, 2].std(), 1e-9 * s) for h, s in zip(local, uv_scale)])
    fits = fit_charts_by_size([h[:, :2] / s for h, s in zip(local, uv_scale)],
                              [h[:, 2] / s for h, s in zip(local, z_scale)], settings=settings, rng=rng,
                              train_mask=_train_masks(charts, train_mask),
                              sigma_floor=floor / z_scale, device=device)
    return fits, uv_scale, z_scale


def _train_masks(charts: list[Chart], train_mask: np.ndarray | None) -> list[np.ndarray] | None:
    """Per chart, ``(n_members,)`` bool: the members that train it (``train_mask`` (N,) if given, as
    for the benchmark's oracle, else the chart's own :attr:`~scanrig.surface.charts.Chart.trained`)."""
    if train_mask is not None:
        return [train_mask[c.members] for c in charts]
    if all(c.trained is None for c in charts):
        return None
    return [np.ones(len(c.members), bool) if c.trained is None else c.trained for c in charts]


def _chart_noise(fits: ChartFits, z_scale: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Per chart, metres: the scale of the rejection point ``b / r``, and how closely the network
    follows its points, the held-out noise scale before the cap of the robust start (a chart
    straddling a step keeps a tight rejection point from its start, but its held-out residuals
    stay large)."""
    sigma_c = fits.b / r * z_scale
    return sigma_c, np.maximum(fits.sigma_upper * z_scale, sigma_c)


def _loose_charts(charts: list[Chart], fits: ChartFits, z_scale: np.ndarray, settings: FitSettings,
                  sigma_floor: float, point_sigma: np.ndarray | None) -> np.ndarray:
    """(C,) bool: charts whose network does not follow their points.

    Held-out noise scale above ``TRUST_FACTOR`` times the reference (``sigma_floor`` if given,
    else the median ``point_sigma`` of the chart's core if given, else the typical chart's), or
    more than ``q`` of the chart's points beyond the rejection point: more bad data than the
    fit tolerates, e.g. a step or a second object's face taken for a cluster of outliers.
    """
    _, sigma_fit = _chart_noise(fits, z_scale, settings.constants.r)
    if sigma_floor > 0:
        reference = np.full(len(charts), sigma_floor)
    elif point_sigma is not None:
        reference = np.array([np.median(point_sigma[c.core]) for c in charts])
    else:
        reference = np.full(len(charts), _typical_noise(charts, sigma_fit))
    return (sigma_fit > TRUST_FACTOR * reference) | (fits.history[-1]["rejected"] > settings.q)


def _typical_noise(charts: list[Chart], sigma_fit: np.ndarray) -> float:
    """Median of the charts' held-out noise scales over the points (each chart weighted by its
    members), metres.

    Not the median over the charts: on 100 000 points of the scan with 10 % outliers, 64 of the
    123 charts were small pieces (54-144 points) of reflection blobs with scales of 3.5-27 sigma;
    they outnumbered the surface charts (1.0-1.2 sigma) and put the median chart at 5.0 sigma,
    so that 54 of them passed the trust test (1.03 sigma over the points).
    """
    sizes = np.array([len(chart.members) for chart in charts], dtype=float)
    order = np.argsort(sigma_fit)
    share = np.cumsum(sizes[order]) / sizes.sum()
    return float(sigma_fit[order][np.searchsorted(share, 0.5)])


def _blend_outputs(points: np.ndarray, normals: np.ndarray, charts: list[Chart], fits: ChartFits,
                   uv_scale: np.ndarray, z_scale: np.ndarray, settings: FitSettings,
                   sigma_floor: float, point_sigma: np.ndarray | None = None) -> FilterResult:
    """Blend the per-chart fits into per-point outputs (see :func:`filter_points`).

    ``residual``, ``score`` and ``sigma`` use the partition of unity of every chart a point is a
    member of. ``denoised`` is guarded so that the filter never makes good data worse: it blends
    only *trusted* charts (noise scale at most ``TRUST_FACTOR`` times ``sigma_floor`` if given,
    else times the typical chart's noise scale: a chart that cannot follow its surface,
    e.g. one that straddles a step, has a noise scale far above the others'),
    whose normal agrees with the point's normal (within the charts' 60 degrees; projecting a
    wall point along a floor chart's normal is meaningless), with inverse-variance weights
    ``(sigma_ref / sigma_c)^2`` so a loose fit never overrides a tight one, and leaves out a
    chart at a point beyond its rejection point ``r sigma_c``: a gross error, or structure the
    fit smooths away (flagged, not projected). With ``point_sigma`` the chart must also be
    within ``POINT_TRUST_FACTOR`` of the point's own sigma and the point within ``r`` of its own
    sigma of the fit: a point is then never moved by more than ``r`` of its own sigmas. A point
    that no such chart covers keeps its measured position. A chart that is not trusted scores
    its points against the reference noise, not its own loose scale: a chart that is no surface
    at the cloud's noise (a blob of reflections) does not vouch for its points (on the
    100 000-point scan, recall of the >= 5 sigma outliers 0.822 instead of 0.708, inlier FRR
    0.0011 instead of 0.0008; the protocol's cells, whose charts are all trusted, unchanged).
    Its points that no trusted chart owns are also scored against the trusted surface around
    them where they form no surface in its frame
    (:func:`~scanrig.surface.surroundings.surroundings_score`; the larger score counts): the
    fit of a chart cut from a blob runs through the blob (same scan: recall 0.919 instead of
    0.817, FRR unchanged).
    """
    n = len(points)
    r = settings.constants.r
    sigma_c, sigma_fit = _chart_noise(fits, z_scale, r)
    # reference noise: the known sensor noise if given, else the typical chart's
    sigma_ref = sigma_floor if sigma_floor > 0 else max(_typical_noise(charts, sigma_fit), 1e-300)
    trusted = sigma_fit <= TRUST_FACTOR * sigma_ref
    cos_max = np.cos(MAX_NORMAL_ANGLE)
    acc = np.zeros((n, 7))  # weight, denoised xyz, residual, score, sigma
    acc_d = np.zeros((n, 4))  # guarded weight, denoised xyz
    for c, chart in enumerate(charts):
        m = len(chart.members)
        own = points[chart.members]
        w = blend_weights(chart, own)
        local = chart.to_chart(own)
        height = fits.z_fit[c, :m] * z_scale[c]
        projected = chart.from_chart(np.column_stack([local[:, :2], height]))
        values = np.column_stack([
            projected,
            local[:, 2] - height,
            np.abs(fits.residual_heldout[c, :m]) * z_scale[c] / (sigma_c[c] if trusted[c] else sigma_ref),
            np.full(m, sigma_c[c]),
        ])
        np.add.at(acc, chart.members, np.column_stack([w, w[:, None] * values]))
        if trusted[c]:
            agree = np.abs(normals[chart.members] @ chart.rotation[2]) >= cos_max
            # a point beyond the rejection point of the fit is flagged, never moved: it is a gross
            # error or it lies on structure the fit smooths away (an edge, a step, a corner),
            # and moving it would make the latter worse
            fits_point = np.abs(local[:, 2] - height) <= r * sigma_c[c]
            if point_sigma is not None:  # absolute reference: the points' own predicted sigma
                own_sigma = np.maximum(point_sigma[chart.members], sigma_floor)
                agree &= sigma_fit[c] <= POINT_TRUST_FACTOR * own_sigma
                fits_point &= np.abs(local[:, 2] - height) <= r * own_sigma
            wd = w * agree * fits_point * (sigma_ref / sigma_fit[c]) ** 2
            np.add.at(acc_d, chart.members, np.column_stack([wd, wd[:, None] * projected]))
    weight = acc[:, 0]
    if np.any(weight <= 0):
        raise RuntimeError("internal error: a point is covered by no chart")
    out = acc[:, 1:] / weight[:, None]
    covered = acc_d[:, 0] > 0
    denoised = points.copy()
    denoised[covered] = acc_d[covered, 1:] / acc_d[covered, :1]
    score = out[:, 4]
    # a point of an untrusted chart that no trusted chart owns is also judged by the trusted surface around it
    owned = np.zeros(n, bool)
    for c in np.flatnonzero(trusted):
        owned[charts[c].core] = True
    score = np.fmax(score, surroundings_score(points, normals, [charts[c] for c in np.flatnonzero(~trusted)], owned,
                                              np.flatnonzero(owned & (score <= r)), sigma_ref, r))
    return FilterResult(denoised=denoised, inlier=score <= r, score=score,
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

    Each chart whose reach (see :func:`~scanrig.surface.charts.blend_weights`) and height window
    cover a point, and that holds there (:meth:`~scanrig.surface.charts.Chart.holds`: at a step,
    only the sheet that owns the point's place in the plane), projects it along its normal; the
    projections are blended with the same partition of unity as the input points. A point
    outside every reach uses the chart with the nearest origin.

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
    weights = np.stack([blend_weights(c, points) * c.in_window(points) * c.holds(points)
                        for c in result.charts])  # (C, m)
    nearest = np.argmin(np.stack([np.linalg.norm(points - c.origin, axis=1) for c in result.charts]), axis=0)
    uncovered = weights.sum(axis=0) <= 0
    weights[nearest[uncovered], np.flatnonzero(uncovered)] = 1.0
    local = np.stack([c.to_chart(points) for c in result.charts])  # (C, m, 3)
    heights = result.fits.predict(local[..., :2] / result.uv_scale[:, None, None]) * result.z_scale[:, None]
    local[..., 2] = heights
    projected = np.stack([c.from_chart(local[i]) for i, c in enumerate(result.charts)])
    return np.einsum("cm,cmk->mk", weights, projected) / weights.sum(axis=0)[:, None]
