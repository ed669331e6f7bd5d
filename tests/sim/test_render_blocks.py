"""Block-wise rendering arithmetic: the same numbers as the whole-array form it replaces."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.sim import laser
from scanrig.sim.laser import GaussianBeams
from scanrig.sim.render import _block_mean


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


def test_beamlets_sum_the_nearest_landings_within_their_reach():
    rng = np.random.default_rng(8)
    beams = _beamlets(rng)
    x = np.column_stack([rng.uniform(-0.07, 0.07, 400), rng.normal(0, 5e-3, 400), np.zeros(400)])
    total = beams.evaluate(x)[0]
    # brute force: the _MAX_NEIGHBOUR_BEAMS nearest landings, each counted within its own reach
    dist = np.linalg.norm(x[:, None] - beams.landing[None], axis=2)
    nearest = np.argsort(dist, axis=1)[:, :laser._MAX_NEIGHBOUR_BEAMS]
    want = np.zeros(len(x))
    for j in range(len(beams.power_W)):
        rel = x - beams.origin[j]
        z = rel @ beams.direction[j]
        w = beams.radius(z, j)
        rho2 = np.einsum("ij,ij->i", rel, rel) - z * z
        inten = 2 * beams.power_W[j] / (np.pi * w * w) * np.exp(-2 * rho2 / (w * w))
        counted = (nearest == j).any(axis=1) & (dist[:, j] <= beams.reach_m[j]) & (z > 0)
        want += np.where(counted, inten, 0.0)
    assert np.count_nonzero(want) > 200
    # rho² = |rel|² - z² cancels (z ≈ |rel|): the two roundings agree to about 1e-12
    np.testing.assert_allclose(total, want, rtol=1e-9, atol=0)
