"""Clipped runs with no crosstalk profile and steep edges: centred on the midpoint of their edges."""

import numpy as np
import pytest

import scanrig
from scanrig.laser import colour_fit
from scanrig.laser.colour_fit import edge_step_px, plateau_midpoint
from scanrig.sim.colour import bayer_demosaic
from tests.laser.colour_synth import stripe_frames

#: Laser channel background and clip, DN, and the noise of every channel, DN.
BG_DN, CLIP_DN, NOISE_DN = 30.0, 255.0, 2.0
#: Window of the unit cases: 17 pixels, the middle at index 8.
WIDTH = 17
#: A centre within this many of its σ of the truth is consistent with it.
Z_MAX = 3.0
#: Accepted robust spread (1.4826 MAD) of error / σ.
Z_SPREAD = (0.6, 1.4)


def plateau_frame(seed, half_width_px=3.2, amplitude_dn=2000.0, crosstalk=0.0, rows=200, cols=96):
    """A red stripe as a band of uniform light ``2 · half_width_px`` wide, ``amplitude_dn`` over
    the background (8 × the range to the clip: its edges rise within a pixel), pixel-integrated,
    green flat (plus ``crosstalk`` of the laser's light), noise ``NOISE_DN`` in every channel.
    Returns the uint8 frame ``(rows, cols, 3)`` and the true centre of each row, px."""
    rng = np.random.default_rng(seed)
    centre = 40.3 + 0.037 * np.arange(rows) + rng.uniform(0.0, 1.0)
    x = np.arange(cols)[None, :]
    lit = np.clip(np.minimum(x + 0.5, centre[:, None] + half_width_px)
                  - np.maximum(x - 0.5, centre[:, None] - half_width_px), 0.0, 1.0)
    img = np.stack([BG_DN + amplitude_dn * lit, 10.0 + crosstalk * amplitude_dn * lit,
                    np.full(lit.shape, 10.0)], axis=2)
    img += rng.normal(0.0, NOISE_DN, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8), centre


def plateau_errors(demosaiced: bool) -> np.ndarray:
    """error / σ of the rank-0 centres of five plateau frames of 200 rows (the edges' sub-pixel
    positions sweep the pixel grid), each through an RGGB mosaic and OpenCV's bilinear demosaicing
    when ``demosaiced``."""
    z = []
    for seed in range(5):
        img, truth = plateau_frame(seed)
        img = bayer_demosaic(img) if demosaiced else img
        t = scanrig.detect_stripe(img, color="red")
        u, line, rank, sigma, clipped = (t[k].to_numpy() for k in ("u", "line", "rank", "sigma_px", "saturated"))
        best = rank == 0
        # the frame's border rows may lack one
        assert best.sum() >= img.shape[0] - 2 and clipped[best].all()
        z.append((u[best] - truth[line[best]]) / sigma[best])
    return np.concatenate(z)


def test_a_sharp_plateau_without_crosstalk_is_centred_within_its_sigma():
    """The rank-0 centres lie within ``Z_MAX`` σ of the truth (but for the chi-square test's rare
    false alarm on a flat channel) and error / σ spreads like a unit normal."""
    z = plateau_errors(demosaiced=False)
    assert np.mean(np.abs(z) <= Z_MAX) >= 0.995
    assert Z_SPREAD[0] <= 1.4826 * np.median(np.abs(z)) <= Z_SPREAD[1]


def test_a_demosaiced_plateau_is_known_to_its_photosites():
    """Through a Bayer mosaic the runs end on the red photosites' grid (parity 13 σ from a fair
    coin), so each edge is known to 2 px: error 0.30 px RMS against σ 0.41 px (spread 0.89; 1.73
    with σ for a pixel per edge)."""
    z = plateau_errors(demosaiced=True)
    assert Z_SPREAD[0] <= 1.4826 * np.median(np.abs(z)) <= Z_SPREAD[1]


def test_the_edge_step_follows_the_parity_of_the_runs_ends():
    """A fair coin's ends (or too few to tell) are known to a pixel; ends on one parity beyond
    ``_PARITY_SIGMAS`` to a photosite period."""
    rng = np.random.default_rng(7)
    fair = rng.integers(0, 1000, 800)
    assert edge_step_px([fair, fair + 1]) == 1.0
    assert edge_step_px([np.array([2, 4, 6]), np.array([9, 11, 13])]) == 1.0
    assert edge_step_px([fair, 2 * fair]) == 2.0
    assert edge_step_px([np.zeros(0, int), np.zeros(0, int)]) == 1.0


def unit_case(inner_share=None, outer_share=None, crosstalk_dn=0.0):
    """One window: clipped pixels 5-10 (middle 8); ``inner_share`` puts pixels 4 and 11 at that
    share of the way from the background to the clip, ``outer_share`` pixels 3 and 12 (and
    ``inner_share`` 4 and 11, clipped when None). Green peaks by ``crosstalk_dn`` in the run's middle."""
    raw = np.full((1, WIDTH), BG_DN)
    raw[0, 5:11] = CLIP_DN
    if inner_share is not None:
        raw[0, [4, 11]] = BG_DN + inner_share * (CLIP_DN - BG_DN)
    if outer_share is not None:
        raw[0, [3, 12]] = BG_DN + outer_share * (CLIP_DN - BG_DN)
    others = np.zeros((1, WIDTH, 2))
    others[0, 5:11, 0] = crosstalk_dn * np.array([0.2, 0.6, 1.0, 1.0, 0.6, 0.2])
    return plateau_midpoint(raw, others, np.ones(others.shape, bool), np.full(2, NOISE_DN), NOISE_DN, CLIP_DN)


def test_edges_without_partial_pixels_are_known_to_a_pixel():
    """Background, then clip: each edge half-way between the two pixels, known to ±0.5 px
    (σ² = 1/12 px² per edge, and the background pixel's noise through the interpolation, half the
    rise away from the level)."""
    out = unit_case()
    assert out["applies"][0]
    assert out["centre"][0] == pytest.approx(-0.5)
    edge_var = 1.0 / 12.0 + (NOISE_DN / (2.0 * (CLIP_DN - BG_DN))) ** 2
    assert np.sqrt(out["var"][0]) == pytest.approx(np.sqrt(2.0 * edge_var) / 2.0)
    assert out["half_length"][0] == pytest.approx(3.0)


def test_edges_with_unclipped_partial_pixels_keep_the_pixel_uncertainty():
    """Pixels 4 and 11 at 80 % of the rise, unclipped: each edge where the laser crosses the half
    level between them and the background, 3/8 px out from them. The run clipped, so the beam's
    level over it is unknown (at least the clip), and with it the share of pixel 4 it lights: each
    edge keeps 1/12 px² besides the noise through the interpolation."""
    out = unit_case(inner_share=0.8)
    assert out["applies"][0]
    assert out["centre"][0] == pytest.approx(-0.5)
    assert out["half_length"][0] == pytest.approx(3.5 + 3.0 / 8.0)
    slope_dn = 0.8 * (CLIP_DN - BG_DN)
    noise_var = (NOISE_DN / slope_dn) ** 2 * ((0.5 - 0.0) ** 2 + (0.8 - 0.5) ** 2) / 0.8**2
    assert out["var"][0] == pytest.approx(2.0 * (1.0 / 12.0 + noise_var) / 4.0)


def test_a_partial_pixel_beyond_a_clipped_one_keeps_the_pixel_uncertainty():
    """Pixels 4 and 11 at 30 % (below the half level) beside clipped pixels: the edge moves out by
    the interpolation but the beam's peak, and so how much of that pixel it lights, is unknown."""
    out = unit_case(inner_share=0.3)
    assert out["applies"][0]
    assert out["centre"][0] == pytest.approx(-0.5)
    assert out["half_length"][0] == pytest.approx(2.5 + 0.5 / 0.7)  # the half level 5/7 of the step out
    assert out["var"][0] >= 2.0 / 12.0 / 4.0


def test_crosstalk_over_the_run_or_a_gentle_edge_keeps_the_colour_fit():
    """Green peaking in the run by 20 noise σ carries the profile; an edge rising over three
    pixels is not steep: the midpoint does not apply to either."""
    assert not unit_case(crosstalk_dn=20 * NOISE_DN)["applies"][0]
    assert not unit_case(inner_share=0.6, outer_share=0.3)["applies"][0]
    assert unit_case(crosstalk_dn=0.5 * NOISE_DN)["applies"][0]


@pytest.mark.parametrize("with_dark", [False, True])
def test_the_rendered_stripe_with_crosstalk_keeps_the_colour_fit(monkeypatch, with_dark):
    """On a rendered over-exposed Gaussian beam with 7 % / 5 % crosstalk (tests/laser/colour_synth.py)
    green and blue peak under the clipped run: the midpoint applies to no clipped candidate."""
    seen = []

    def spy(*args, **kwargs):
        out = plateau_midpoint(*args, **kwargs)
        seen.append(out["applies"])
        return out

    monkeypatch.setattr(colour_fit, "plateau_midpoint", spy)
    on, off, _ = stripe_frames(np.random.default_rng(0))
    scanrig.detect_stripe(on, color="red", dark=off if with_dark else None)
    applies = np.concatenate(seen)
    assert applies.size > 400
    assert not applies.any()
