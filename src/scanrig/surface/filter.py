"""The whole-cloud robust filter: charts, robust network fits, blending, per-point outputs."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from scanrig.errors import InputError, ShapeError
from scanrig.geometry.checks import check_points
from scanrig.surface.charts import (MIN_CHART_POINTS, Chart, blend_weights, estimate_normals, halve_charts,
                                    split_charts)
from scanrig.surface.hampel import check_q, refined_scale
from scanrig.surface.memory import keep_freed_memory
from scanrig.surface.chart_batches import fit_charts_by_size
from scanrig.surface.fit_settings import FitSettings
from scanrig.surface.robust_fit import ChartFits, concatenate_fits
from scanrig.surface.sheets import split_sheets
from scanrig.surface.sparse import SPARSE_CHART_POINTS, SUPPORT_POINTS, local_quadratic_scores
from scanrig.surface.surroundings import surroundings_score
from scanrig.surface.tiles import TILE_POINTS, TILE_WORKERS, filter_in_tiles, tile_margin

MIN_POINTS = 16  # below this a surface network (2 folds x several points) is meaningless
#: A chart whose noise scale exceeds this multiple of the reference noise (``sigma_floor``, else
#: the typical chart's, :func:`_typical_noise`) is not trusted: it moves no point, and its
#: points are scored against the reference instead of its own loose fit; one that exceeds it
#: times ``sigma_floor``, else its points' median own sigma, else the typical chart's, is
#: halved (:func:`_loose_charts`). Points of known sigma: see ``POINT_TRUST_FACTOR``. Nor is a
#: chart of fewer than ``SPARSE_CHART_POINTS`` members trusted, whatever its noise scale (see
#: :func:`_blend_outputs`).
TRUST_FACTOR = 3.0
#: A chart moves a point whose own sigma is known only if its held-out noise scale is at most
#: this multiple of that sigma. The held-out scale is ``sqrt(sigma_point^2 + s_fold^2)`` with
#: ``s_fold`` the error of a fold network's prediction; the full network, trained on twice the
#: points, errs by about ``s_fold / sqrt(2)``, and replacing the point by the fit helps only if
#: that is below ``sigma_point``: ``sqrt(3)``. With ``TRUST_FACTOR`` (3) instead, a 62-point
#: demo cloud of one chart (held-out scale 0.30 mm, median point sigma 0.09 mm) moved a point from
#: 0.13 mm to 0.39 mm off the true surface.
POINT_TRUST_FACTOR = float(np.sqrt(3.0))
#: Fraction of a cloud's points in small charts that makes it a sparse cloud (see :func:`_sparse_points`).
SPARSE_CLOUD_FRACTION = 0.5
#: Least-squares epochs of the networks of sparse charts (see :func:`filter_points`); the
#: local quadratics judge their points.
SPARSE_EPOCHS = 100
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
        around it, see :func:`_blend_outputs`; for a ``sparse`` point, against its local robust
        quadratic, see :func:`_sparse_outputs`); dimensionless, larger is more suspicious.
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
    sparse : (N,) bool array or None
        Points judged by local robust quadratics instead of their chart's network (cores of
        charts with fewer than ``SPARSE_CHART_POINTS`` members, see :mod:`scanrig.surface.sparse`).
    measured : (N, 3) float array or None
        The input points, metres.
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
    sparse: np.ndarray | None = None
    measured: np.ndarray | None = None

    def summary(self) -> dict:
        """What the filter did, so that figures over the kept points never stand alone.

        Returns
        -------
        dict
            ``n_points`` (input points), ``n_removed`` (flagged, not inliers), ``n_sparse``
            (judged by local quadratics, :mod:`scanrig.surface.sparse`), ``rms_residual_inliers_m``
            (RMS distance of the kept points from the fitted surface, metres) and
            ``rms_residual_all_m`` (the same over every input point), and
            ``rms_denoised_shift_all_m`` (RMS of how far the denoised positions moved the input
            points, all of them, metres).
        """
        residual = np.nan_to_num(self.residual)
        kept = self.inlier
        shift = np.linalg.norm(self.denoised - self.measured, axis=1) if self.measured is not None else np.zeros(0)
        return {"n_points": len(kept), "n_removed": int(np.count_nonzero(~kept)),
                "n_sparse": int(np.count_nonzero(self.sparse)) if self.sparse is not None else 0,
                "rms_residual_inliers_m": float(np.sqrt(np.mean(residual[kept] ** 2))) if kept.any() else float("nan"),
                "rms_residual_all_m": float(np.sqrt(np.mean(residual ** 2))),
                "rms_denoised_shift_all_m": float(np.sqrt(np.mean(shift ** 2))) if shift.size else 0.0}


def filter_points(points: np.ndarray, *, rng: np.random.Generator, q: float = 0.25,
                  settings: FitSettings | None = None, max_chart_points: int = 4096,
                  sigma_floor: float = 0.0, device: str = "cpu",
                  train_mask: np.ndarray | None = None,
                  point_sigma: np.ndarray | None = None) -> FilterResult:
    """Robustly fit a surface to a point cloud, flag bad points and denoise the good ones.

    The charts with at least ``SPARSE_CHART_POINTS`` members are fitted by the robust networks
    and refined; in a sparse cloud (at least ``SPARSE_CLOUD_FRACTION`` of its points in smaller
    charts) the points of smaller charts are judged by local robust quadratics against the
    noise learnt on the dense charts (``sigma_floor`` or ``point_sigma`` when given; see
    :mod:`scanrig.surface.sparse`), and their charts' networks are fitted by least squares on
    the points kept, for projections only: they move no point. A cloud of more than
    ``TILE_POINTS`` points is filtered in tiles with overlapping margins, ``TILE_WORKERS`` at a
    time on the CPU, so that memory is bounded by the tiles (:mod:`scanrig.surface.tiles`).

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
        absolute reference for ``denoised`` and for judging sparse points. A chart moves a point only if its noise scale is
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
    args = dict(q=q, settings=settings, max_chart_points=max_chart_points, sigma_floor=sigma_floor, device=device)
    if len(points) <= TILE_POINTS:
        return _filter_cloud(points, rng=rng, train_mask=train_mask, point_sigma=point_sigma, **args)

    def filter_tile(work: np.ndarray, tile_rng: np.random.Generator) -> FilterResult:
        return _filter_cloud(points[work], rng=tile_rng, **args,
                             train_mask=None if train_mask is None else train_mask[work],
                             point_sigma=None if point_sigma is None else point_sigma[work])

    # tiles side by side, torch's threads shared among them (the same arithmetic whatever the
    # threads: every network trains on one, see ``fit_charts_by_size``), so that one tile's
    # single-threaded steps (normals, charts, blending) overlap another's training
    threads = torch.get_num_threads()
    workers = max(1, min(threads, TILE_WORKERS)) if device == "cpu" else 1
    torch.set_num_threads(threads // workers)
    try:
        return filter_in_tiles(points, filter_tile, rng=rng, max_points=TILE_POINTS,
                               margin=tile_margin(points, max_chart_points, rng), workers=workers)
    finally:
        torch.set_num_threads(threads)


def _filter_cloud(points: np.ndarray, *, rng: np.random.Generator, q: float, settings: FitSettings,
                  max_chart_points: int, sigma_floor: float, device: str, train_mask: np.ndarray | None,
                  point_sigma: np.ndarray | None) -> FilterResult:
    """:func:`filter_points` on checked input, the cloud at once."""
    workers = torch.get_num_threads()  # the networks' threads: of the neighbours and sheets too
    normals = estimate_normals(points, workers=workers)
    r = settings.constants.r
    charts = split_sheets(points, normals, split_charts(points, normals, max_points=max_chart_points, q=q),
                          q=q, cut=r, point_sigma=point_sigma, workers=workers)
    sparse = _sparse_points(charts, len(points))
    is_sparse = np.array([sparse[c.core].all() for c in charts])
    fitted = []  # (charts, fits, uv_scale, z_scale) of the dense charts, then of the sparse ones
    if not is_sparse.all():
        fitted.append(_fit_refined(points, normals, [c for c, s in zip(charts, is_sparse) if not s], settings, rng,
                                   train_mask, sigma_floor, device, point_sigma))
    judged = np.flatnonzero(sparse)
    sparse_outputs = None
    if judged.size:
        # the noise learnt where the data are dense (the typical dense chart's), unless known
        noise = sigma_floor
        if noise <= 0 and fitted:
            dense_charts, dense_fits, _, dense_z = fitted[0]
            noise = _typical_noise(dense_charts, _chart_noise(dense_fits, dense_z, r)[1])
        if point_sigma is not None:
            noise = np.maximum(point_sigma[judged], sigma_floor)
        sparse_outputs = _sparse_outputs(points, normals, judged, noise, q, rng)
    if is_sparse.any():
        # their networks serve the projections and the mesh only: least squares on the points the
        # local quadratics keep (or on ``train_mask``), the plain schedule
        kept = np.ones(len(points), bool)
        kept[judged] = sparse_outputs[0] <= r
        for chart in charts:  # a network needs a few points per fold
            if kept[chart.members].sum() < 2 * settings.n_folds:
                kept[chart.members] = True
        fitted.append((sparse_charts := [c for c, s in zip(charts, is_sparse) if s],
                       *_fit(points, sparse_charts, replace(settings, loss="mse", epochs=SPARSE_EPOCHS), rng,
                             kept if train_mask is None else train_mask, sigma_floor, device, point_sigma)))
    charts = [c for part in fitted for c in part[0]]
    fits = fitted[0][1] if len(fitted) == 1 else concatenate_fits([part[1] for part in fitted],
                                                                  np.arange(len(charts)))
    uv_scale, z_scale = (np.concatenate([part[i] for part in fitted]) for i in (2, 3))
    return _blend_outputs(points, normals, charts, fits, uv_scale, z_scale, settings, sigma_floor, rng,
                          point_sigma, sparse=sparse, sparse_outputs=sparse_outputs)


def _fit_refined(points: np.ndarray, normals: np.ndarray, charts: list[Chart], settings: FitSettings,
                 rng: np.random.Generator, train_mask: np.ndarray | None, sigma_floor: float, device: str,
                 point_sigma: np.ndarray | None) -> tuple[list[Chart], ChartFits, np.ndarray, np.ndarray]:
    """Fit the charts' networks, then halve and refit those that cannot follow their surface (a
    side of a step too small to be a sheet, a network that failed), up to ``REFINE_ROUNDS`` times.

    Returns the final charts, their fits, uv and height scales (C,).
    """
    q, r = settings.q, settings.constants.r
    fits, uv_scale, z_scale = _fit(points, charts, settings, rng, train_mask, sigma_floor, device, point_sigma)
    for _ in range(REFINE_ROUNDS):
        loose = _loose_charts(charts, fits, z_scale, settings, sigma_floor, point_sigma)
        loose &= np.array([len(c.core) >= 2 * MIN_CHART_POINTS for c in charts])
        if not loose.any():
            break
        halves = split_sheets(points, normals,
                              halve_charts(points, normals, [c for c, bad in zip(charts, loose) if bad], q=q),
                              q=q, cut=r, point_sigma=point_sigma, workers=torch.get_num_threads())
        if train_mask is not None and min(train_mask[h.members].sum() for h in halves) < 2 * settings.n_folds:
            break  # a half of points left out of training has nothing to fit: keep the charts
        new_fits, new_uv_scale, new_z_scale = _fit(points, halves, settings, rng, train_mask, sigma_floor, device,
                                                   point_sigma)
        keep = np.flatnonzero(~loose)
        fits = concatenate_fits([fits, new_fits], np.concatenate([keep, len(charts) + np.arange(len(halves))]))
        charts = [charts[i] for i in keep] + halves
        uv_scale = np.concatenate([uv_scale[keep], new_uv_scale])
        z_scale = np.concatenate([z_scale[keep], new_z_scale])
    return charts, fits, uv_scale, z_scale


def _sparse_points(charts: list[Chart], n: int) -> np.ndarray:
    """(n,) bool: the core points of charts with fewer than ``SPARSE_CHART_POINTS`` members, too
    few for their network's judgement (see :mod:`scanrig.surface.sparse`), in a cloud where they
    are at least ``SPARSE_CLOUD_FRACTION`` of the points; none otherwise.

    A dense cloud has small charts too: pieces that the normal test cut from blobs of
    reflections (100 000 points of the simulated scan: 83 of 123 charts, 54-400 members, most of
    them all outliers). Their points form a surface locally, and judged by local quadratics the
    blobs' outliers passed (recall of the >= 5 sigma outliers 0.58 instead of 0.91); the
    networks and the trusted surface around them judge them.
    """
    sparse = np.zeros(n, bool)
    for chart in charts:
        if len(chart.members) < SPARSE_CHART_POINTS:
            sparse[chart.core] = True
    return sparse if sparse.mean() >= SPARSE_CLOUD_FRACTION else np.zeros(n, bool)


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


def _trusted(charts: list[Chart], sigma_fit: np.ndarray, sigma_ref: float) -> np.ndarray:
    """(C,) bool: charts whose fits vouch for their points (see :func:`_blend_outputs`): held-out
    noise scale ``sigma_fit`` (C,) at most ``TRUST_FACTOR`` times the reference noise ``sigma_ref``
    (metres) and at least ``SPARSE_CHART_POINTS`` members."""
    members = np.array([len(chart.members) for chart in charts])
    return (sigma_fit <= TRUST_FACTOR * sigma_ref) & (members >= SPARSE_CHART_POINTS)


def _blend_outputs(points: np.ndarray, normals: np.ndarray, charts: list[Chart], fits: ChartFits,
                   uv_scale: np.ndarray, z_scale: np.ndarray, settings: FitSettings,
                   sigma_floor: float, rng: np.random.Generator, point_sigma: np.ndarray | None = None, *,
                   sparse: np.ndarray | None = None, sparse_outputs: tuple | None = None) -> FilterResult:
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

    A chart with fewer than ``SPARSE_CHART_POINTS`` members is not trusted either, whatever its
    noise scale: its networks have as few points as a sparse chart's, too few for their held-out
    residuals to vouch for a surface (``_sparse_points``). In a sparse cloud such charts, a half
    of a dense chart cut that small by the refinement included, moved points off the surface (a
    box on a floor in charts of 300 points: two such halves, 161 and 198 members, one of them
    straddling an edge, moved floor points up to 7 noise sigmas off it, 1-6 % worse in RMS on 13
    of 16 weight seeds; with this, none). In a dense cloud they are the pieces that the normal
    test cut from blobs of reflections, 30-60 core points each, whose networks (some 700 weights)
    follow a slice of the blob to within 2-3 reference noise scales: the pieces passed as
    trusted, their points as inliers, and those points as the trusted surface around the rest of
    the blob (the 1 000 000-point scan: recall of the >= 5 sigma outliers 0.865 instead of 0.789,
    inlier FRR 0.0007 both; the 100 000-point scan: 0.927 instead of 0.918, FRR 0.0012 instead
    of 0.0011; the protocol's cells unchanged).

    The ``sparse`` points (:func:`_sparse_points`) take their score, residual and sigma from
    ``sparse_outputs`` (:func:`_sparse_outputs`, in the order of ``np.flatnonzero(sparse)``), and
    charts of sparse points move no point.
    """
    n = len(points)
    r = settings.constants.r
    sparse = np.zeros(n, bool) if sparse is None else sparse
    dense = np.array([not sparse[c.core].all() for c in charts])
    sigma_c, sigma_fit = _chart_noise(fits, z_scale, r)
    # reference noise: the known sensor noise if given, else the typical dense chart's
    typical = _typical_noise(*((charts, sigma_fit) if dense.all() or not dense.any()
                               else ([c for c, d in zip(charts, dense) if d], sigma_fit[dense])))
    sigma_ref = sigma_floor if sigma_floor > 0 else max(typical, 1e-300)
    trusted = _trusted(charts, sigma_fit, sigma_ref)
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
        if trusted[c] and dense[c]:
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
    score, residual, sigma = out[:, 4], out[:, 3], out[:, 5]
    # a point of an untrusted chart that no trusted chart owns is also judged by the trusted surface around it
    owned = sparse.copy()
    for c in np.flatnonzero(trusted & dense):
        owned[charts[c].core] = True
    score = np.fmax(score, surroundings_score(points, normals, [charts[c] for c in np.flatnonzero(~trusted & dense)],
                                              owned, np.flatnonzero(owned & ~sparse & (score <= r)), sigma_ref, r,
                                              rng=rng, workers=torch.get_num_threads()))
    if sparse_outputs is not None:
        judged = np.flatnonzero(sparse)
        score[judged], residual[judged], sigma[judged] = sparse_outputs
    return FilterResult(denoised=denoised, inlier=score <= r, score=score,
                        residual=residual, sigma=sigma, charts=charts, fits=fits,
                        uv_scale=uv_scale, z_scale=z_scale, settings=settings, sparse=sparse, measured=points)


def _sparse_outputs(points: np.ndarray, normals: np.ndarray, judged: np.ndarray, noise: float | np.ndarray, q: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Score, residual (metres) and noise scale (metres) of sparse points, each (m,).

    Each point is judged by the least-trimmed-squares quadratic of its neighbours
    (:func:`~scanrig.surface.sparse.local_quadratic_scores`): its score is its held-out residual
    over the larger of ``noise * sqrt(1 + g)`` and the fit's local misfit, and 0 where the fit
    does not pass near the point (fewer than ``SUPPORT_POINTS`` kept neighbours close to it).
    ``noise`` is the known noise (scalar or per point, metres) or the typical dense chart's; 0
    when the cloud has neither, and then the robust scale (breakdown point ``q``) of the points'
    own standardised residuals.
    """
    residual, g, misfit, support = local_quadratic_scores(points, normals, judged, rng=rng)
    spread = np.sqrt(1.0 + g)
    if np.all(np.asarray(noise) <= 0):
        noise = refined_scale(residual / spread, q)[0]
    scale = np.maximum(np.maximum(noise * spread, misfit), 1e-300)
    score = np.where(support >= SUPPORT_POINTS, np.abs(residual) / scale, 0.0)
    return score, residual, scale


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
