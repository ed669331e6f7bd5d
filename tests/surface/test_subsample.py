"""Stratified training subsample of dense charts, and fits whose hidden layers learn from it."""

import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.surface.chart_batches import fit_charts_by_size
from scanrig.surface.fit_settings import FitSettings
from scanrig.surface.subsample import stratified_subsample

from .conftest import SIGMA, tilted_plane_with_outliers


def test_subsample_keeps_k_points_spread_over_the_area():
    rng = np.random.default_rng(0)
    dense = rng.uniform(0.0, 0.1, (900, 2))  # a blob in one corner
    sparse = rng.uniform(0.0, 1.0, (100, 2))
    uv = np.stack([np.vstack([dense, sparse]), rng.uniform(0.0, 1.0, (1000, 2))])
    mask = np.ones((2, 1000), dtype=bool)
    mask[1, 150:] = False  # chart 1 has 150 points: no more than k, kept whole
    keep = stratified_subsample(uv, mask, 200, np.random.default_rng(1))
    assert keep[0].sum() == 200 and not np.any(keep & ~mask)
    np.testing.assert_array_equal(keep[1], mask[1])
    # a draw uniform over the points would keep about 20 of the 100 spread ones; every occupied
    # cell of the 15 x 15 grid gives one point first, and the blob fills only 4 of them
    assert keep[0, 900:].sum() >= 90
    np.testing.assert_array_equal(keep, stratified_subsample(uv, mask, 200, np.random.default_rng(1)))


def test_bad_subsample_sizes_are_rejected():
    with pytest.raises(InputError, match=r"k \(training points per chart\) must be >= 1, got 0"):
        stratified_subsample(np.zeros((1, 3, 2)), np.ones((1, 3), dtype=bool), 0, np.random.default_rng(0))
    with pytest.raises(InputError, match="train_points must be >= 0, got -1"):
        FitSettings(train_points=-1)


def test_a_fit_trained_on_a_subsample_judges_and_fits_every_point():
    rng = np.random.default_rng(3)
    points, truth, bad, offset = tilted_plane_with_outliers(rng, n_side=32, eps=0.2)
    settings = FitSettings(train_points=300)
    fits = fit_charts_by_size([points[:, :2]], [points[:, 2]], settings=settings, rng=np.random.default_rng(0))
    z_fit, flagged = fits.z_fit[0], np.abs(fits.residual_heldout[0]) > fits.b[0]
    # a fit through n points of noise sigma errs by about sigma * sqrt(dof / n); the default
    # network's effective dof on this plane are ~150-200 (0.37 sigma from all 1024 points,
    # 0.56-0.59 from 600, 0.76-0.86 from 300 on two weight seeds): below the noise from 300
    assert np.sqrt(np.mean((z_fit - truth)[~bad] ** 2)) < SIGMA
    # the scores are computed for all 1024 points, not the 300 trained on
    far = bad & (offset >= 6 * SIGMA)
    assert flagged[far].mean() > 0.97 and flagged[~bad].mean() < 0.02
