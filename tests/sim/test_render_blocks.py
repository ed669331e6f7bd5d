"""Block-wise rendering arithmetic: the same numbers as the whole-array form it replaces."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.sim import laser
from scanrig.sim import pixel_integration as pi
from scanrig.sim.laser import GaussianBeams
from scanrig.sim.pixel_rays import PixelRayTable, _to_world
from scanrig.sim.render import _block_mean

from .conftest import strong_camera


@pytest.mark.parametrize("s", [1, 2, 3, 4, 7, 8, 9, 16, 17, 32])
@pytest.mark.parametrize("shape", [(13, 17), (1, 5), (5, 1), (1, 1), (40, 2)])
def test_block_mean_is_numpys_mean_to_the_bit(s, shape):
    rng = np.random.default_rng(s * 100 + shape[0])
    fine = (rng.random((shape[0] * s, shape[1] * s)) ** 6 * 1e4).astype(np.float32)
    fine[rng.random(fine.shape) < 0.3] = 0.0
    want = fine.reshape(shape[0], s, shape[1], s).mean(axis=(1, 3))
    got = _block_mean(fine, s)
    assert got.dtype == want.dtype and got.shape == want.shape
    assert np.array_equal(got, want)


def _beamlets(rng, m=60):
    """Secondary beamlets landing along a line on z = 0, reaches 1-20 mm."""
    landing = np.column_stack([np.linspace(-0.05, 0.05, m), rng.normal(0, 1e-3, m), np.zeros(m)])
    direction = np.column_stack([rng.normal(0, 0.2, m), rng.normal(0, 0.2, m), -np.ones(m)])
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    origin = landing - 0.3 * direction
    waist = rng.uniform(2e-4, 5e-4, m)
    return GaussianBeams(origin, direction, waist, np.zeros(m), waist / 0.02, rng.uniform(1e-5, 1e-4, m),
                         emitter_normal=np.tile([0.0, 0.0, 1.0], (m, 1)), landing=landing,
                         reach_m=rng.uniform(1e-3, 2e-2, m))


def test_beamlets_evaluated_block_by_block_give_the_same_bits(monkeypatch):
    rng = np.random.default_rng(7)
    beams = _beamlets(rng)
    x = np.column_stack([rng.uniform(-0.07, 0.07, 5000), rng.normal(0, 5e-3, 5000), np.zeros(5000)])
    whole = beams.evaluate(x)
    monkeypatch.setattr(laser, "_EVAL_BLOCK", 97)        # many blocks, a partial last one
    blocks = GaussianBeams(**{k: v for k, v in vars(beams).items() if not k.startswith("_")}).evaluate(x)
    for a, b in zip(whole, blocks):
        assert np.array_equal(a, b)


def test_beamlets_tested_block_by_block_may_light_the_same_points(monkeypatch):
    rng = np.random.default_rng(9)
    beams = _beamlets(rng)
    x = np.column_stack([rng.uniform(-0.07, 0.07, 5000), rng.normal(0, 5e-3, 5000), np.zeros(5000)])
    reach_m = rng.uniform(0.0, 2e-3, 5000)
    whole = beams.may_light(x, reach_m)
    assert 0 < whole.mean() < 1
    monkeypatch.setattr(laser, "_EVAL_BLOCK", 97)
    assert np.array_equal(whole, beams.may_light(x, reach_m))


def test_beamlets_sum_every_landing_within_its_reach():
    rng = np.random.default_rng(8)
    beams = _beamlets(rng, m=120)
    x = np.column_stack([rng.uniform(-0.07, 0.07, 400), rng.normal(0, 5e-3, 400), np.zeros(400)])
    total = beams.evaluate(x)[0]
    # brute force: every beamlet at every point within its own reach of its landing
    dist = np.linalg.norm(x[:, None] - beams.landing[None], axis=2)
    counted = dist <= beams.reach_m
    # many points are within reach of more landings than a nearest-few search would keep
    assert np.count_nonzero(counted.sum(axis=1) > 24) > 50
    want = np.zeros(len(x))
    for j in range(len(beams.power_W)):
        rel = x - beams.origin[j]
        z = rel @ beams.direction[j]
        w = beams.radius(z, j)
        rho2 = np.einsum("ij,ij->i", rel, rel) - z * z
        inten = 2 * beams.power_W[j] / (np.pi * w * w) * np.exp(-2 * rho2 / (w * w))
        want += np.where(counted[:, j] & (z > 0), inten, 0.0)
    assert np.count_nonzero(want) > 200
    # rho² = |rel|² - z² cancels (z ≈ |rel|): the two roundings agree to about 1e-12
    np.testing.assert_allclose(total, want, rtol=1e-9, atol=0)


def test_the_dominant_beamlet_is_the_brightest_at_each_point():
    rng = np.random.default_rng(9)
    beams = _beamlets(rng)
    x = np.column_stack([rng.uniform(-0.07, 0.07, 400), rng.normal(0, 5e-3, 400), np.zeros(400)])
    total, propagation, _ = beams.evaluate(x)
    lit = total > 0
    rel = x[:, None] - beams.origin[None]                                  # (n, m, 3)
    z = np.einsum("nmj,mj->nm", rel, beams.direction)
    w = beams.radius(z)
    rho2 = np.einsum("nmj,nmj->nm", rel, rel) - z * z
    inten = 2 * beams.power_W / (np.pi * w * w) * np.exp(-2 * rho2 / (w * w))
    inten[(np.linalg.norm(x[:, None] - beams.landing[None], axis=2) > beams.reach_m) | (z <= 0)] = 0.0
    brightest = inten.argmax(axis=1)
    assert np.count_nonzero(lit) > 200
    np.testing.assert_array_equal(propagation[lit], beams.direction[brightest[lit]])


def test_pixel_rays_by_planes_are_the_pairwise_forms_bits():
    """PixelRayTable interpolates and rotates one coordinate at a time; the (N, 2) pair forms it
    replaced give the same bits."""
    rng = np.random.default_rng(11)
    table = PixelRayTable(strong_camera())
    xy = table.xy
    h, w = xy.shape[:2]
    q = np.column_stack([rng.uniform(-0.5, w - 0.5, 20000), rng.uniform(-0.5, h - 0.5, 20000)])
    # the pair form: rows of (x, y) gathered and blended together
    flat = xy.reshape(-1, 2)
    u0 = np.minimum(np.clip(q[:, 0], 0.0, w - 1.0).astype(np.int64), w - 2)
    v0 = np.minimum(np.clip(q[:, 1], 0.0, h - 1.0).astype(np.int64), h - 2)
    fu, fv = (q[:, 0] - u0)[:, None], (q[:, 1] - v0)[:, None]
    i00 = v0 * w + u0
    top = flat[i00] + (flat[i00 + 1] - flat[i00]) * fu
    bottom = flat[i00 + w] + (flat[i00 + w + 1] - flat[i00 + w]) * fu
    pairs = top + (bottom - top) * fv
    R = table._R
    want = (pairs @ R[:, :2].T + R[:, 2]) / np.sqrt(np.einsum("ij,ij->i", pairs, pairs) + 1.0)[:, None]
    assert np.array_equal(table.rays(q)[1], want)
    assert np.array_equal(_to_world(pairs, R), want)


def test_edge_taps_by_planes_are_the_pairwise_forms_bits():
    """Edge sample offsets one axis per plane and the PSF taps tap-first: the same bits as the
    (n, s², 2) offsets and (n, s², T) taps they replaced."""
    rng = np.random.default_rng(12)
    centres = np.column_stack([rng.integers(0, 1280, 500), rng.integers(0, 1024, 500)]).astype(np.float64)
    s, reach, sigma_px = 8, 3, 0.6
    shift = (centres[:, 1] * 65536.0 + centres[:, 0])[:, None] * pi.R2_STEPS[None, :]
    shift = np.mod(shift, 1.0)
    pairs = np.mod(pi._base_pattern(s)[None] + shift[:, None, :], 1.0) - 0.5
    planes = pi.edge_sample_offsets(centres, s)
    assert np.array_equal(np.moveaxis(planes, 0, 2), pairs)
    table = pi._box_gauss_table(reach, sigma_px).T                      # (points, taps)
    x = (pairs[:, :, 0] + 0.5) * pi._TABLE_POINTS
    i = np.clip(x.astype(np.int64), 0, pi._TABLE_POINTS - 1)
    f = (x - i)[..., None]
    want = table[i] * (1.0 - f) + table[i + 1] * f                      # (n, s², T)
    assert np.array_equal(np.moveaxis(pi._box_gauss_taps(planes[0], reach, sigma_px), 0, 2), want)
