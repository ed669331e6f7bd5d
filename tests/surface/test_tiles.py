"""Large clouds in tiles, and chart groups trained side by side, without changing results."""

import numpy as np
import torch

import scanrig.surface.filter as filter_module
import scanrig.surface.chart_batches as chart_batches
from scanrig.surface.chart_batches import fit_charts_by_size
from scanrig.surface.fit_settings import FitSettings
from scanrig.surface.tiles import split_tiles

from .conftest import FAST, SIGMA, tilted_plane_with_outliers


def test_tiles_partition_the_cloud_within_the_size():
    points = np.random.default_rng(0).uniform(-1, 1, (1001, 3))
    tiles = split_tiles(points, 300)
    assert all(len(t) <= 300 for t in tiles) and len(tiles) == 4
    np.testing.assert_array_equal(np.sort(np.concatenate(tiles)), np.arange(len(points)))


def test_a_cloud_filtered_in_tiles_is_judged_and_denoised_throughout(monkeypatch):
    points, truth, bad, offset = tilted_plane_with_outliers(np.random.default_rng(3), n_side=48, eps=0.1)
    monkeypatch.setattr(filter_module, "TILE_POINTS", 1200)  # 2304 points: two tiles
    result = filter_module.filter_points(points, rng=np.random.default_rng(0), settings=FAST,
                                         max_chart_points=400)
    cores = np.concatenate([c.core for c in result.charts])
    np.testing.assert_array_equal(np.sort(cores), np.arange(len(points)))  # the cores still partition
    assert result.fits.z_fit.shape[0] == len(result.charts) == len(result.uv_scale)
    error = result.denoised[~bad, 2] - truth[~bad]
    assert np.sqrt(np.mean(error ** 2)) < SIGMA  # the fit averages the noise down, tile borders too
    far = bad & (offset >= 5 * SIGMA)
    assert np.mean(~result.inlier[far]) >= 0.95 and np.mean(~result.inlier[~bad]) <= 0.01


def test_tiles_side_by_side_give_the_same_result_as_one_after_the_other(monkeypatch):
    points, _, _, _ = tilted_plane_with_outliers(np.random.default_rng(4), n_side=40, eps=0.1)
    monkeypatch.setattr(filter_module, "TILE_POINTS", 500)  # 1600 points: four tiles
    threads_seen = []
    filter_cloud = filter_module._filter_cloud

    def recording(*args, **kwargs):
        threads_seen.append(torch.get_num_threads())
        return filter_cloud(*args, **kwargs)

    monkeypatch.setattr(filter_module, "_filter_cloud", recording)
    results = []
    for threads in (1, 2):  # 2: two tiles at a time, one torch thread each
        torch.set_num_threads(threads)
        results.append(filter_module.filter_points(points, rng=np.random.default_rng(0), settings=FAST,
                                                   max_chart_points=300))
    assert torch.get_num_threads() == 2 and threads_seen == [1] * 8
    for name in ("denoised", "score", "inlier", "residual", "sigma"):
        np.testing.assert_array_equal(getattr(results[0], name), getattr(results[1], name))
    np.testing.assert_array_equal(results[0].fits.z_fit, results[1].fits.z_fit)
    assert [c.core.tolist() for c in results[0].charts] == [c.core.tolist() for c in results[1].charts]


def test_chart_groups_give_the_same_fits_side_by_side_or_one_after_the_other(monkeypatch):
    rng = np.random.default_rng(5)
    sizes = [300, 200, 120, 80]
    uv = [rng.uniform(-1, 1, (n, 2)) for n in sizes]
    z = [0.3 * p[:, 0] + rng.normal(0, SIGMA, n) for p, n in zip(uv, sizes)]
    settings = FitSettings(hidden=6, depth=1, epochs=40, robust_epochs=40, update_every=20, start_epochs=10,
                           n_boot=50)
    monkeypatch.setattr(chart_batches, "FIT_GROUPS_MIN_POINTS", 0)
    fits = []
    for threads in (1, 2):  # 2: the groups train in two threads
        torch.set_num_threads(threads)
        fits.append(fit_charts_by_size(uv, z, settings=settings, rng=np.random.default_rng(0)))
    assert torch.get_num_threads() == 2  # restored after the groups
    np.testing.assert_array_equal(fits[0].z_fit, fits[1].z_fit)
    np.testing.assert_array_equal(fits[0].sigma_upper, fits[1].sigma_upper)


def test_one_group_trains_on_one_thread_whatever_the_thread_count(monkeypatch):
    """A cloud too small for two groups trains on one torch thread too: split among threads, a sum
    adds in another order, and an early stop turns that last bit into another fit (the demo's
    filtered points differed between one and two threads)."""
    rng = np.random.default_rng(6)
    sizes = [300, 150]
    uv = [rng.uniform(-1, 1, (n, 2)) for n in sizes]
    z = [0.3 * p[:, 0] + rng.normal(0, SIGMA, n) for p, n in zip(uv, sizes)]
    settings = FitSettings(hidden=6, depth=1, epochs=40, robust_epochs=40, update_every=20, start_epochs=10,
                           n_boot=50)
    seen = []
    fit_batches = chart_batches._fit_batches

    def recording(*args, **kwargs):
        seen.append(torch.get_num_threads())
        return fit_batches(*args, **kwargs)

    monkeypatch.setattr(chart_batches, "_fit_batches", recording)
    fits = []
    for threads in (1, 2):
        torch.set_num_threads(threads)
        fits.append(fit_charts_by_size(uv, z, settings=settings, rng=np.random.default_rng(0)))
    assert seen == [1, 1] and torch.get_num_threads() == 2
    np.testing.assert_array_equal(fits[0].z_fit, fits[1].z_fit)
