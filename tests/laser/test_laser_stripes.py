"""Stripe detection: every peak on every line, at the Cramér–Rao bound, any orientation."""

import numpy as np
import pytest

import scanrig
from scanrig.errors import InputError
from scanrig.laser.crb import crb_stripe, effective_noise

from .synth import integrated, quantize, spot_image, stripe_image

AMPLITUDE, BACKGROUND, NOISE = 180.0, 10.0, 2.0
RMS_OVER_CRB_MAX = 1.2
BIAS_MAX_PX = 0.02
SIGMA_RATIO_RANGE = (0.8, 1.25)


def _curve(lines):
    """A tilted, curved stripe: every sub-pixel offset occurs along it."""
    return 640.3 + 0.113 * lines + 40.0 * np.sin(lines / 150.0)


@pytest.mark.parametrize("sigma", [0.8, 1.5, 2.5])
def test_stripe_centres_reach_the_cramer_rao_bound_without_bias(sigma):
    rng = np.random.default_rng(401 + int(10 * sigma))
    errors, offsets, ratios = [], [], []
    for _ in range(3):
        t = scanrig.detect_stripe(stripe_image((1024, 1280), _curve, rng, AMPLITUDE, sigma, BACKGROUND, NOISE))
        assert len(t) == 1024 and np.all(t["rank"].to_numpy() == 0)
        line = t["line"].to_numpy().astype(float)
        np.testing.assert_array_equal(t["v"].to_numpy(), line)
        true_u = _curve(line)
        errors.append(t["u"].to_numpy() - true_u)
        offsets.append(true_u - np.rint(true_u))
        ratios.append(errors[-1] / t["sigma_px"].to_numpy())
    err, off = np.concatenate(errors), np.concatenate(offsets)
    bound = crb_stripe(AMPLITUDE, sigma, off, effective_noise(NOISE))
    assert np.sqrt(np.mean(err**2)) <= RMS_OVER_CRB_MAX * np.sqrt(np.mean(bound**2))
    bins = np.digitize(off, np.linspace(-0.5, 0.5, 6)[1:-1])
    assert max(abs(err[bins == k].mean()) for k in range(5)) <= BIAS_MAX_PX
    assert SIGMA_RATIO_RANGE[0] <= np.std(np.concatenate(ratios)) <= SIGMA_RATIO_RANGE[1]


def test_horizontal_stripe_is_scanned_along_columns():
    rng = np.random.default_rng(402)
    img = stripe_image((480, 640), lambda c: 200.4 + 0.05 * c, rng, AMPLITUDE, 1.5, BACKGROUND, NOISE, along="columns")
    t = scanrig.detect_stripe(img)
    assert len(t) == 640
    line = t["line"].to_numpy()
    np.testing.assert_array_equal(t["u"].to_numpy(), line)
    np.testing.assert_allclose(t["v"].to_numpy(), 200.4 + 0.05 * line, atol=0.1)
    assert np.all(t["cov_uu"].to_numpy() == 0) and np.all(t["cov_vv"].to_numpy() > 0)


def test_every_peak_on_a_line_is_reported_and_ranked():
    """The true stripe and a brighter reflection 25 px away: both on every row, reflection rank 0."""
    rng = np.random.default_rng(403)
    x = np.arange(400, dtype=float)
    prof = AMPLITUDE * integrated(x, 150.3, 1.5) + 1.5 * AMPLITUDE * integrated(x, 175.8, 2.0)
    img = quantize(BACKGROUND + prof[None, :] + rng.normal(0, NOISE, (300, 400)))
    t = scanrig.detect_stripe(img, direction="rows")
    assert len(t) == 600
    u, rank = t["u"].to_numpy(), t["rank"].to_numpy()
    assert np.all(np.abs(u[rank == 1] - 150.3) < 0.1) and np.all(np.abs(u[rank == 0] - 175.8) < 0.1)


def test_saturated_core_with_coloured_fringes():
    """A red laser 4x over the clip: the core is white (all channels clipped), the fringes red."""
    rng = np.random.default_rng(404)
    g = integrated(np.arange(200.0), 100.4, 2.0)[None, :] * np.ones((60, 1))
    rgb = quantize(np.stack([10 + 900 * g, 12 + 250 * g, 8 + 250 * g], axis=-1) + rng.normal(0, NOISE, (60, 200, 3)))
    t = scanrig.detect_stripe(rgb, color="red")
    assert len(t) == 60 and t["saturated"].to_numpy().all()
    err = t["u"].to_numpy() - 100.4
    assert np.sqrt(np.mean(err**2)) < 0.05  # tails-only fit; the unclipped CRB is 0.011 px
    assert SIGMA_RATIO_RANGE[0] <= np.std(err / t["sigma_px"].to_numpy()) <= 1.5  # 60 samples


def test_stripe_across_dark_and_bright_texture():
    """Grey texture steps of 0..120 DN under a red stripe: colour differencing removes them."""
    rng = np.random.default_rng(405)
    texture = np.repeat(np.repeat(rng.integers(0, 120, (8, 10)), 40, axis=0), 40, axis=1).astype(float)
    g = AMPLITUDE * integrated(np.arange(400.0), 210.6, 1.5)[None, :]
    rgb = quantize(np.stack([texture + g, texture, texture], axis=-1) + rng.normal(0, NOISE, (320, 400, 3)))
    t = scanrig.detect_stripe(rgb, color="red")
    assert len(t) == 320
    assert np.abs(t["u"].to_numpy() - 210.6).max() < 0.15


def test_dark_frame_and_noise_give_no_candidates():
    rng = np.random.default_rng(406)
    assert len(scanrig.detect_stripe(np.zeros((200, 300), np.uint16))) == 0
    false = sum(len(scanrig.detect_stripe(spot_image((1024, 1280), [], rng, BACKGROUND, NOISE))) for _ in range(10))
    assert false == 0


def test_bad_direction_is_rejected():
    with pytest.raises(InputError, match="direction must be one of .* got 'diagonal'"):
        scanrig.detect_stripe(np.zeros((20, 20), np.uint8), direction="diagonal")


def test_curved_stripe_is_crossed_by_rows_where_steep_and_columns_where_flat():
    """A ring of radius 600 px through a 640 x 512 frame turns from nearly vertical to nearly
    horizontal; every detection lies on it, and both scan directions are used."""
    rng = np.random.default_rng(407)
    v, u = np.mgrid[0:512, 0:640].astype(float)
    radius, centre = 600.0, (-100.0, -100.0)
    ring = AMPLITUDE * np.exp(-0.5 * ((np.hypot(u - centre[0], v - centre[1]) - radius) / 1.5) ** 2)
    img = quantize(BACKGROUND + ring + rng.normal(0, NOISE, ring.shape))
    t = scanrig.detect_stripe(img)
    dist = np.hypot(t["u"].to_numpy() - centre[0], t["v"].to_numpy() - centre[1]) - radius
    # the ring is not pixel-integrated and curves by 1/600 px⁻¹: about 0.01 px of model error
    assert np.sqrt(np.mean(dist**2)) < 0.03 and np.abs(dist).max() < 0.1
    by_columns = t["cov_uu"].to_numpy() == 0
    assert 0.25 < by_columns.mean() < 0.75
    # the 741 px of arc in the frame cross about 650 scan lines (each line crosses where the arc is
    # steeper than 45° to it); 5 % may be lost at the block boundaries between directions
    assert len(t) > 0.95 * 650


def test_sigma_stays_honest_under_shot_noise():
    """Pixel variance 4 + signal (1 e-/DN, peak 180 DN): the peak is 7x noisier than the background.
    The per-frame shot-noise slope brings the error / sigma spread back to about 1 (it is about 1.8
    with background noise alone)."""
    rng = np.random.default_rng(408)
    centres = 640.0 + rng.uniform(-0.5, 0.5, 1024)
    signal = AMPLITUDE * integrated(np.arange(1280.0)[None, :], centres[:, None], 1.5)
    img = quantize(BACKGROUND + signal + rng.normal(0, 1, signal.shape) * np.sqrt(NOISE**2 + signal))
    t = scanrig.detect_stripe(img)
    assert len(t) == 1024
    err = t["u"].to_numpy() - centres[t["line"].to_numpy()]
    assert SIGMA_RATIO_RANGE[0] <= np.std(err / t["sigma_px"].to_numpy()) <= SIGMA_RATIO_RANGE[1]
