"""Fitting the charts of a cloud: batches of similar size, two groups side by side.

:func:`~scanrig.surface.robust_fit.fit_charts` trains one batch of charts padded to the largest;
:func:`fit_charts_by_size` cuts a cloud's charts (tens to thousands of points) into the batches
that waste least time and deals them into ``FIT_GROUPS`` groups that train at once, one torch
thread each.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch

from scanrig.surface.fit_settings import FitSettings
from scanrig.surface.robust_fit import ChartFits, concatenate_fits, fit_charts

#: Fixed cost of fitting one batch of charts, in padded points: a batch of one small chart took
#: 0.85 s (the schedule's ~460 epochs of Python and dispatch, with 200 Hampel epochs) against
#: 0.31 ms per padded point in large batches (100 000 points, 2 cores, measured).
BATCH_OVERHEAD_POINTS = 2500
#: Groups of charts that :func:`fit_charts_by_size` trains side by side (the cores of the 2-core
#: machine the filter is benchmarked on); fixed, so that results do not depend on the threads.
FIT_GROUPS = 2
#: Fewest chart members (summed) that are dealt into ``FIT_GROUPS`` groups; below, one group.
FIT_GROUPS_MIN_POINTS = 20_000


def fit_charts_by_size(uv: list[np.ndarray], z: list[np.ndarray], *, settings: FitSettings,
                       rng: np.random.Generator, train_mask: list[np.ndarray] | None = None,
                       sigma_floor: np.ndarray | float = 0.0, device: str = "cpu",
                       overhead_points: float = BATCH_OVERHEAD_POINTS) -> ChartFits:
    """:func:`fit_charts` on charts of different sizes, in batches that waste little time.

    A batch pads every chart to its largest; a cloud's charts range from tens to thousands of
    points (a real stripe scan: 34 to 5600), and one batch of all of them was 25-50x its points
    in rows, nearly all padding, while one batch per size cost a fixed overhead each. The
    charts, sorted by size, are cut into the batches that minimise the modelled time
    ``sum(overhead_points + n_max * n_charts)`` (dynamic programming, :func:`_size_batches`);
    the fits are merged in input order. Each chart's fit is independent of its batch (same
    schedule, its own weights).

    The charts of a cloud of at least ``FIT_GROUPS_MIN_POINTS`` members, sorted by size, are dealt
    alternately into ``FIT_GROUPS`` groups of about equal work, the first drawing from ``rng``,
    the others from generators spawned from it (a smaller cloud is one group: its results, on
    which the protocol's figures were measured, stay those of one stream). With
    torch's intra-op threads at ``FIT_GROUPS`` or more, the groups train at the same time, one
    thread each: the networks' operations are too small to keep two threads of one operation
    busy, and whole groups side by side are not. On the CPU every group trains on one torch
    thread (torch's threads set to 1 meanwhile), a single group too: split among threads, a
    matrix product or a sum adds in an order that depends on the thread count and the batch's
    shape, and a network's early stop (``converge_every``) turns such last-bit differences into
    different fits. So the arithmetic, and the result, do not depend on the thread count.

    Parameters
    ----------
    uv : list of (n_c, 2) float arrays
        Normalised coordinates of each chart's members.
    z : list of (n_c,) float arrays
        Normalised heights.
    settings, rng, sigma_floor, device
        As in :func:`fit_charts`.
    train_mask : list of (n_c,) bool arrays, optional
        As in :func:`fit_charts`, per chart.
    overhead_points : float
        Fixed cost of a batch, in padded points.

    Returns
    -------
    ChartFits
        Arrays padded to the largest chart, charts in input order.
    """
    sizes = np.array([len(h) for h in z])
    floor = np.broadcast_to(np.asarray(sigma_floor, dtype=float), sizes.shape)
    order = np.argsort(-sizes, kind="stable")
    n_groups = FIT_GROUPS if sizes.sum() >= FIT_GROUPS_MIN_POINTS else 1
    dealt = [np.sort(order[i::n_groups]) for i in range(n_groups) if i < len(order)]
    generators = [rng, *rng.spawn(len(dealt) - 1)]

    def fit_group(charts: np.ndarray, group_rng: np.random.Generator) -> ChartFits:
        return _fit_batches([uv[c] for c in charts], [z[c] for c in charts], settings=settings,
                            rng=group_rng, train_mask=None if train_mask is None else [train_mask[c] for c in charts],
                            sigma_floor=floor[charts], device=device, overhead_points=overhead_points)

    if device != "cpu":
        parts = [fit_group(charts, group_rng) for charts, group_rng in zip(dealt, generators)]
        return concatenate_fits(parts, np.argsort(np.concatenate(dealt)))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        if len(dealt) > 1 and threads >= FIT_GROUPS:
            with ThreadPoolExecutor(len(dealt)) as pool:
                parts = list(pool.map(fit_group, dealt, generators))
        else:
            parts = [fit_group(charts, group_rng) for charts, group_rng in zip(dealt, generators)]
    finally:
        torch.set_num_threads(threads)
    return concatenate_fits(parts, np.argsort(np.concatenate(dealt)))


def _fit_batches(uv: list[np.ndarray], z: list[np.ndarray], *, settings: FitSettings, rng: np.random.Generator,
                 train_mask: list[np.ndarray] | None, sigma_floor: np.ndarray, device: str,
                 overhead_points: float) -> ChartFits:
    """One group of charts of :func:`fit_charts_by_size` (arguments as there, ``sigma_floor``
    (C,)), in batches of similar size one after the other; fits in the group's order."""
    sizes = np.array([len(h) for h in z])
    groups = _size_batches(sizes, overhead_points)
    parts = []
    for group in groups:
        n_max = sizes[group].max()
        uv_g = np.zeros((len(group), n_max, 2))
        z_g = np.zeros((len(group), n_max))
        valid = np.zeros((len(group), n_max), dtype=bool)
        mask = None if train_mask is None else np.zeros((len(group), n_max), dtype=bool)
        for row, c in enumerate(group):
            uv_g[row, :sizes[c]], z_g[row, :sizes[c]], valid[row, :sizes[c]] = uv[c], z[c], True
            if mask is not None:
                mask[row, :sizes[c]] = train_mask[c]
        parts.append(fit_charts(uv_g, z_g, valid, settings=settings, rng=rng, train_mask=mask,
                                sigma_floor=sigma_floor[group], device=device))
    return concatenate_fits(parts, np.argsort(np.concatenate(groups)))


def _size_batches(sizes: np.ndarray, overhead: float) -> list[np.ndarray]:
    """Cut charts into batches minimising ``sum(overhead + largest size * count)``.

    Parameters
    ----------
    sizes : (C,) int array
    overhead : float
        Fixed cost of a batch, in padded points.

    Returns
    -------
    list of int arrays
        Chart indices of each batch, largest charts first.
    """
    order = np.argsort(-sizes, kind="stable")
    s = sizes[order].astype(float)
    best = np.zeros(len(s) + 1)
    start = np.zeros(len(s) + 1, dtype=int)
    for end in range(1, len(s) + 1):  # a batch [j, end) of the sorted sizes is padded to s[j]
        cost = best[:end] + overhead + s[:end] * (end - np.arange(end))
        start[end] = np.argmin(cost)
        best[end] = cost[start[end]]
    batches, end = [], len(s)
    while end > 0:
        batches.append(order[start[end]:end])
        end = start[end]
    return batches[::-1]
