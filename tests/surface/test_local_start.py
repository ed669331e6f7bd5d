"""The high-breakdown start: local trimmed planes keep clustered one-sided outliers out."""

import numpy as np
import pytest

from scanrig.surface.local_start import fill_with_quadratic, local_trimmed_planes, robust_start, trimmed_planes

from .conftest import SIGMA


def clustered_outliers(rng, n_side=40, eps=0.4):
    """Grid on a tilted plane; a fraction eps of outliers, half uniform, half in 4 blobs above.

    Returns uv (N, 2), z (N,), outlier mask (N,), offset from the true plane (N,).
    """
    g = np.linspace(-1, 1, n_side)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    uv = np.column_stack([x, y])
    truth = 0.3 * x - 0.2 * y
    z = truth + rng.normal(0, SIGMA, x.size)
    n_bad = int(eps * x.size)
    bad = np.zeros(x.size, bool)
    uniform = rng.choice(x.size, n_bad // 2, replace=False)
    bad[uniform] = True
    centres = rng.uniform(-0.7, 0.7, (4, 2))
    near = np.argsort(np.linalg.norm(uv[:, None] - centres, axis=2), axis=0)[: n_bad // 8].ravel()
    bad[near] = True
    z[uniform] += rng.uniform(-0.5, 0.5, uniform.size)
    z[near] += rng.uniform(5 * SIGMA, 0.3, near.size)
    return uv, z, bad, z - truth


def test_local_planes_see_the_noise_on_a_clean_plane():
    rng = np.random.default_rng(3)
    g = np.linspace(-1, 1, 40)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    z = 0.3 * x - 0.2 * y + rng.normal(0, SIGMA, x.size)
    residual, scale = local_trimmed_planes(np.column_stack([x, y]), z)
    # held-out residual of a plane from ~13 kept neighbours: sigma * sqrt(1 + ~3/13), ~1600 points
    assert SIGMA <= np.sqrt(np.mean(residual**2)) <= 1.2 * SIGMA
    # the trimmed scale of a neighbourhood is a noisy but consistent estimate of sigma
    assert 0.8 * SIGMA <= np.median(scale) <= 1.25 * SIGMA


def test_start_keeps_clustered_outliers_out_at_40_percent():
    rng = np.random.default_rng(4)
    uv, z, bad, offset = clustered_outliers(rng)
    good, sigma_upper = robust_start(uv[None], z[None], np.ones((1, len(z)), bool), q=0.5, cut=4.0,
                                     rng=np.random.default_rng(0))
    good = good[0]
    # the scale is the inliers' (held-out residual ~1.1 sigma), not inflated by the 40 % bad points
    assert SIGMA <= sigma_upper[0] <= 1.5 * SIGMA
    far = bad & (np.abs(offset) >= 5 * SIGMA)  # nearer ones are indistinguishable from noise
    assert np.mean(good[far]) <= 0.05
    assert np.mean(good[~bad]) >= 0.85


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_start_scale_comes_from_surface_neighbourhoods(seed):
    # inside a blob of reflections (all bad, 5-30 sigma above) a point's held-out residual from
    # its neighbours' trimmed plane is spread over the blob's height range, and some of them fall
    # within the noise band; they are no evidence of the noise. From every residual the bound
    # was 1.23-1.27 sigma on these draws.
    uv, z, bad, offset = clustered_outliers(np.random.default_rng(seed), n_side=64)
    _, sigma_upper = robust_start(uv[None], z[None], np.ones((1, len(z)), bool), q=0.5, cut=4.0,
                                  rng=np.random.default_rng(0))
    # a clean plane's held-out residual is sigma * sqrt(1 + ~3/13) = 1.11 sigma, its bootstrap
    # bound a few per cent above
    assert sigma_upper[0] <= 1.2 * SIGMA


def test_start_scale_is_never_below_the_floor():
    # the points' own sigma, 10x the scatter that neighbours along a stripe see
    rng = np.random.default_rng(5)
    uv = rng.uniform(-1, 1, (400, 2))
    z = 0.1 * SIGMA * rng.standard_normal(len(uv))
    good, sigma_upper = robust_start(uv[None], z[None], np.ones((1, len(z)), bool), q=0.25, cut=4.0,
                                     rng=np.random.default_rng(0), sigma_floor=SIGMA)
    assert sigma_upper[0] == SIGMA
    assert good.all()


def _reference_trimmed_plane(du, zn, keep=0.5, steps=6):
    """One set's LTS plane by the definition: concentration steps, each a least-squares fit of
    the ceil(keep k) points of smallest residual (numpy lstsq)."""
    k = len(zn)
    h = min(k, max(4, int(np.ceil(keep * k))))
    design = np.column_stack([np.ones(k), du])
    coef = np.array([np.median(zn), 0.0, 0.0])
    for _ in range(steps):
        kept = np.argsort(np.abs(zn - design @ coef))[:h]
        coef = np.linalg.lstsq(design[kept], zn[kept], rcond=None)[0]
    return coef


@pytest.mark.parametrize("k", [16, 24])  # the sizes used (start, sheets)
def test_trimmed_planes_match_the_definition(k):
    rng = np.random.default_rng(k)
    du = rng.uniform(-1, 1, (200, k, 2))
    zn = 0.3 * du[..., 0] - 0.1 * du[..., 1] + 0.2 + rng.normal(0, SIGMA, (200, k))
    bad = rng.random((200, k)) < 0.3
    zn[bad] += rng.uniform(5 * SIGMA, 0.5, bad.sum())
    coef, _ = trimmed_planes(du, zn)
    expected = np.array([_reference_trimmed_plane(d, z) for d, z in zip(du, zn)])
    # the ridge of 1e-9 of the Gram trace shifts the solution by ~1e-8 (sigma is 1e-2)
    np.testing.assert_allclose(coef, expected, atol=1e-6)


def test_fill_keeps_good_heights_and_puts_the_quadratic_in_the_holes():
    # a saddle with a hole of outliers over its corner, as a cluster of reflections at a chart's
    # border: the fill there is the quadratic through the good points (exact for a quadratic)
    rng = np.random.default_rng(4)
    uv = rng.uniform(-1, 1, (2, 500, 2))
    true = 0.5 * (uv[..., 0] ** 2 - uv[..., 1] ** 2) + 0.1 * uv[..., 0]
    z = true + rng.normal(0, SIGMA, true.shape)
    good = ~((uv[..., 0] < -0.5) & (uv[..., 1] < -0.5))
    z[~good] += 0.3
    valid = np.ones(true.shape, bool)
    valid[1, 450:] = False  # padding of the second chart
    filled = fill_with_quadratic(uv, z, valid, good)
    np.testing.assert_array_equal(filled[good & valid], z[good & valid])
    hole = ~good & valid
    # least squares through n noisy points: the quadratic is off by ~sigma sqrt(6/n) inside, a few
    # times that where it extrapolates into the corner
    assert np.sqrt(np.mean((filled[hole] - true[hole]) ** 2)) < 0.5 * SIGMA


def test_fill_of_a_chart_with_too_few_good_points_is_finite():
    uv = np.array([[[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [0.2, 0.7]]])  # three good points on a line
    z = np.array([[1.0, 1.5, 2.0, 9.0]])
    good = np.array([[True, True, True, False]])
    filled = fill_with_quadratic(uv, z, np.ones_like(good), good)
    assert np.all(np.isfinite(filled))
    np.testing.assert_allclose(filled[0, :3], z[0, :3])
