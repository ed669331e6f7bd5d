"""filter_points on a contaminated plane, and bad input."""

import dataclasses

import numpy as np
import pytest

from scanrig.errors import InputError, ShapeError
from scanrig.surface import filter_points, mesh_from_result

from .conftest import FAST, SIGMA, tilted_plane_with_outliers


@pytest.fixture(scope="module")
def plane_result():
    rng = np.random.default_rng(20261123)
    points, truth, bad, offset = tilted_plane_with_outliers(rng)
    robust = filter_points(points, rng=np.random.default_rng(1), q=0.25, settings=FAST)
    mse = filter_points(points, rng=np.random.default_rng(1), q=0.25,
                        settings=dataclasses.replace(FAST, loss="mse"))
    return points, truth, bad, robust, mse


def vertical_error(result, truth_fn):
    d = result.denoised
    return d[:, 2] - truth_fn(d[:, 0], d[:, 1])


def plane(x, y):
    return 0.3 * x - 0.2 * y + 0.1


def test_outputs_have_one_row_per_input_point(plane_result):
    points, _, _, robust, _ = plane_result
    n = len(points)
    assert robust.denoised.shape == (n, 3)
    assert robust.inlier.shape == robust.score.shape == robust.residual.shape == (n,)
    assert robust.inlier.dtype == bool and np.all(np.isfinite(robust.score))


def test_rejects_gross_errors_and_keeps_inliers(plane_result):
    _, _, bad, robust, _ = plane_result
    # offsets >= 5 sigma: the ideal detector at 1 % false alarms finds 99 % of them
    assert np.mean(~robust.inlier[bad]) >= 0.95
    assert np.mean(~robust.inlier[~bad]) <= 0.01


def test_denoises_below_the_noise_and_beats_least_squares(plane_result):
    _, _, bad, robust, mse = plane_result
    err = np.sqrt(np.mean(vertical_error(robust, plane)[~bad] ** 2))
    err_mse = np.sqrt(np.mean(vertical_error(mse, plane)[~bad] ** 2))
    # 1024 points, ~150 network parameters: the floor sigma*sqrt(p/n) is ~0.4 sigma
    assert err < 0.5 * SIGMA
    # 20 % outliers with mean offset ~0.15 m bias least squares by ~0.03 m >> sigma
    assert err_mse > 5 * err
    # the residual is the signed distance to the fit: outliers sit above it
    assert np.median(robust.residual[bad]) > 5 * SIGMA


def test_noise_scale_is_recovered(plane_result):
    robust = plane_result[3]
    # sigma+ is a 95 % upper bound from ~800 held-out residuals (SE ~2.5 %), inflated by the
    # held-out model's own variance (~10 %)
    assert SIGMA <= np.median(robust.sigma) <= 1.25 * SIGMA


def test_mesh_covers_the_inliers(plane_result):
    robust = plane_result[3]
    vertices, faces = mesh_from_result(robust)
    assert len(vertices) == robust.inlier.sum()
    # a Delaunay triangulation of n points in a convex domain has ~2n triangles
    assert len(faces) > 1.5 * len(vertices)
    assert faces.min() >= 0 and faces.max() < len(vertices)


@pytest.mark.parametrize("points, match", [
    (np.zeros((0, 3)), "at least"),
    (np.full((100, 3), np.nan), "finite"),
])
def test_bad_clouds_are_rejected(points, match):
    with pytest.raises(InputError, match=match):
        filter_points(points, rng=np.random.default_rng(0))


def test_bad_shape_and_q_are_rejected():
    with pytest.raises(ShapeError):
        filter_points(np.zeros((100, 2)), rng=np.random.default_rng(0))
    with pytest.raises(InputError, match="q"):
        filter_points(np.zeros((100, 3)), rng=np.random.default_rng(0), q=0.7)


def test_a_train_mask_that_leaves_a_half_chart_empty_stops_the_refinement():
    # the oracle's mask leaves the bent half (x > 0) out of training: the chart cannot follow it
    # and is halved, and the half x > 0 would have no point to train on (an InputError before)
    rng = np.random.default_rng(3)
    g = np.linspace(-1, 1, 40)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    truth = 0.5 * np.clip(x, 0, None) ** 2
    z = truth + rng.normal(0, SIGMA, x.size)
    train = x < 0
    res = filter_points(np.column_stack([x, y, z]), rng=rng, settings=dataclasses.replace(FAST, loss="mse"),
                        train_mask=train)
    assert len(res.charts) > 1  # one round of halving was made
    for chart in res.charts:
        assert train[chart.members].sum() >= 2 * FAST.n_folds
    assert np.sqrt(np.mean((res.denoised[train, 2] - truth[train]) ** 2)) < SIGMA  # denoised where trained
