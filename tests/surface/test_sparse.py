"""Sparse clouds: points of charts too small for their network are judged by local robust quadratics."""

from pathlib import Path

import numpy as np
import pytest

from scanrig.io.ply import read_points_with_sigma
from scanrig.surface.charts import estimate_normals
from scanrig.surface.filter import filter_points
from scanrig.surface.hampel import HampelConstants
from scanrig.surface import sparse
from scanrig.surface.sparse import QUADRIC_NEIGHBOURS, local_quadratic_scores

from .conftest import FAST

DATA = Path(__file__).parent / "data"
NOISE = 20e-6  # metres, along the normal
R = HampelConstants().r  # the rejection point, in noise scales


def sphere_with_outliers(rng, n=1500, radius=0.05, eps=0.15):
    """``n`` points uniform on a sphere (mean spacing ~4.6 mm), normal noise NOISE, a fraction
    ``eps`` of them 20-250 NOISE off either side. Returns points (n, 3) and the outlier mask."""
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    offset = rng.normal(0, NOISE, n)
    bad = rng.random(n) < eps
    offset[bad] = rng.choice([-1.0, 1.0], bad.sum()) * rng.uniform(20, 250, bad.sum()) * NOISE
    return direction * (radius + offset)[:, None], bad


def assert_good_kept_and_outliers_rejected(points, bad, rng) -> np.ndarray:
    """Judge every point by :func:`local_quadratic_scores` with the noise known; assert the
    limits (>= 98 % of the good points kept, >= 95 % of the outliers rejected) and return the
    support counts."""
    residual, g, misfit, support = local_quadratic_scores(points, estimate_normals(points), np.arange(len(points)),
                                                          rng=rng)
    flagged = np.abs(residual) / np.maximum(NOISE * np.sqrt(1 + g), misfit) > R
    assert np.mean(~flagged[~bad]) >= 0.98
    assert np.mean(flagged[bad]) >= 0.95
    return support


@pytest.mark.parametrize("seed", [0, 1])
def test_local_quadratics_keep_the_good_points_and_reject_far_outliers(seed):
    # the limits: >= 98 % of the good points kept, >= 95 % of the outliers >= 20 sigma rejected;
    # on capsules of 1,500 points the networks of their charts (60-300 points) kept 86-93 % and
    # rejected 8-90 %
    rng = np.random.default_rng(seed)
    points, bad = sphere_with_outliers(rng)
    support = assert_good_kept_and_outliers_rejected(points, bad, rng)
    assert np.all(support >= 0) and np.all(support <= QUADRIC_NEIGHBOURS)


def thin_cylinder_with_outliers(rng, n=600, radius=0.03, spacing=0.015, eps=0.1):
    """``n`` points uniform on a cylinder along x of ``radius`` (12 points around it at
    ``spacing``), normal noise NOISE, a fraction ``eps`` of them 20-250 NOISE off either side.
    Returns points (n, 3) and the outlier mask."""
    length = n * spacing**2 / (2 * np.pi * radius)
    angle = rng.uniform(0, 2 * np.pi, n)
    offset = rng.normal(0, NOISE, n)
    bad = rng.random(n) < eps
    offset[bad] = rng.choice([-1.0, 1.0], bad.sum()) * rng.uniform(20, 250, bad.sum()) * NOISE
    rho = radius + offset
    return np.column_stack([rng.uniform(0, length, n), rho * np.cos(angle), rho * np.sin(angle)]), bad


def test_a_clean_cylinder_is_a_quadric_where_a_quadratic_cannot_follow_it(monkeypatch):
    # 15 mm apart on a 30 mm radius the neighbours span most of a half-turn: a quadratic height
    # field misses them by several noise sigmas, the quadric through them is exact (rounding)
    rng = np.random.default_rng(11)
    points, _ = thin_cylinder_with_outliers(rng, eps=0.0)
    points[:, 1:] *= 0.03 / np.linalg.norm(points[:, 1:], axis=1, keepdims=True)  # no noise
    normals, judged = estimate_normals(points), np.arange(0, len(points), 5)
    residual, _, misfit, _ = local_quadratic_scores(points, normals, judged, rng=rng)
    assert np.max(np.abs(residual)) < 1e-2 * NOISE
    assert np.max(misfit) < 1e-2 * NOISE
    monkeypatch.setattr(sparse, "QUADRIC_PREFERENCE", 1e12)  # the quadratics alone
    _, _, quadratic_misfit, _ = local_quadratic_scores(points, normals, judged, rng=rng)
    assert np.median(quadratic_misfit) > 3 * NOISE


@pytest.mark.parametrize("seed", [0, 1])
def test_local_quadrics_judge_a_cylinder_sampled_at_half_its_radius(seed):
    # the limits of the sphere test above; the quadratics alone rejected 67-74 % of the outliers
    # of such capsules
    rng = np.random.default_rng(seed)
    points, bad = thin_cylinder_with_outliers(rng)
    assert_good_kept_and_outliers_rejected(points, bad, rng)


def test_local_quadratic_of_a_clean_plane_is_exact():
    # a plane is a quadratic height field in any frame: the held-out residuals vanish (rounding)
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.05, 0.05, (400, 2))
    points = np.column_stack([xy, 0.7 * xy[:, 0] - 0.2 * xy[:, 1] + 0.01])
    residual, _, misfit, support = local_quadratic_scores(points, estimate_normals(points), np.arange(0, 400, 7),
                                                          rng=rng)
    assert np.max(np.abs(residual)) < 1e-3 * NOISE
    assert np.max(misfit) < 1e-3 * NOISE
    assert np.all(support >= 4)


def test_the_spot_demo_cloud_loses_no_good_point():
    # 62 spots in clusters of ~6, 10 mm apart, over a floor, a stepped block, an I-beam and a
    # ball; every one within 1.5 of its own sigmas of the true surface. The networks of its one
    # chart flagged 15-18 of them (the ball's six at 120-270 sigma from the floor's fit).
    points, sigma = read_points_with_sigma(DATA / "demo_spot_points.ply")
    result = filter_points(points, rng=np.random.default_rng(0), settings=FAST, point_sigma=sigma)
    assert result.sparse.all()
    assert result.inlier.all()
    assert result.summary()["n_removed"] == 0


def test_summary_counts_the_removed_points_and_the_rms_over_all():
    rng = np.random.default_rng(4)
    points, bad = sphere_with_outliers(rng, n=300)
    result = filter_points(points, rng=rng, settings=FAST)
    summary = result.summary()
    assert summary["n_points"] == 300 and summary["n_removed"] == int(np.count_nonzero(~result.inlier))
    assert summary["n_sparse"] == 300  # every chart of 300 points is sparse
    residual = np.nan_to_num(result.residual)
    assert summary["rms_residual_all_m"] == pytest.approx(np.sqrt(np.mean(residual ** 2)))
    assert summary["rms_residual_all_m"] >= summary["rms_residual_inliers_m"]
    assert summary["rms_denoised_shift_all_m"] == 0.0  # sparse charts move no point
