"""Candidates where the laser channel is unknown (scanrig.laser.clipped_runs): a camera that turns a
saturated red beam white, a glint clipped in every channel, and the run's edge midpoint."""

import numpy as np
import pytest

import scanrig
from scanrig.laser.clipped_runs import BAYER_PERIOD_PX, fit_unknown_runs, unknown_laser
from scanrig.laser.image import prepare_image
from tests.laser.synth import integrated, quantize

SHAPE = (96, 80)
#: Laser-off scene (R, G, B), DN, and the noise σ of each channel, DN.
SCENE_DN, NOISE_DN = np.array([60.0, 50.0, 45.0]), 1.5
#: The beam: peak in red (DN, 6 × full scale), width (σ, px), crosstalk into green and blue.
PEAK_DN, BEAM_SIGMA_PX, CROSSTALK = 1500.0, 1.3, (0.04, 0.03)
#: The camera's processing turns a pixel whose red exceeds this (DN) into this grey (R, G, B).
WHITEN_ABOVE_DN, WHITE_DN = 400.0, np.array([110.0, 120.0, 105.0])
#: Rows where the camera whitens the beam (elsewhere red clips at 255 as usual).
WHITENED_ROWS = slice(30, 70)
#: The camera cuts the beam at whole pixels: each edge of a run is known to the pixel step, and
#: their midpoint to half of it, px.
HALF_STEP_PX = 0.5


def frames(seed: int):
    """Laser-on and laser-off uint8 frames of a near-vertical red stripe and its true centre per row."""
    rng = np.random.default_rng(seed)
    h, w = SHAPE
    centre = 39.3 + 0.03 * np.arange(h)
    beam = PEAK_DN * integrated(np.arange(w)[None, :], centre[:, None], BEAM_SIGMA_PX)  # (H, W) red, DN
    lit = SCENE_DN + beam[..., None] * np.array([1.0, *CROSSTALK])
    whitened = np.zeros((h, w), bool)
    whitened[WHITENED_ROWS] = beam[WHITENED_ROWS] > WHITEN_ABOVE_DN
    lit[whitened] = WHITE_DN
    on = quantize(lit + rng.normal(0.0, NOISE_DN, lit.shape))
    off = quantize(SCENE_DN + rng.normal(0.0, NOISE_DN, lit.shape))
    return on, off, centre, whitened


def test_whitened_beam_pixels_are_found_and_nothing_else():
    """Every whitened pixel; besides them only red's clipped core, where green and blue rise with
    the beam's crosstalk."""
    on, off, _, whitened = frames(0)
    px = unknown_laser(prepare_image(on, "red", off, None, None, None))
    found = np.zeros(SHAPE, bool)
    found[px.v, px.u] = True
    assert np.all(found[whitened])
    assert np.all(on[found & ~whitened, 0] == 255)
    np.testing.assert_array_equal(px.whitened, whitened[px.v, px.u])


def test_each_whitened_row_gets_one_centre_on_the_beam_with_the_bayer_sigma():
    """The run's edges are where the camera's threshold cut the beam: symmetric about it, so the
    midpoint is within half a pixel step of the true centre."""
    on, off, centre, whitened = frames(1)
    fit = fit_unknown_runs(prepare_image(on, "red", off, None, None, None), True)
    rows = np.flatnonzero(whitened.any(axis=1))
    np.testing.assert_array_equal(np.sort(fit["line"]), rows)
    order = np.argsort(fit["line"])
    assert np.all(np.abs(fit["centre"][order] - centre[rows]) <= HALF_STEP_PX)
    assert np.all(fit["saturated"])
    # the noise of the edges adds little to the photosite period's share
    np.testing.assert_allclose(fit["sigma_px"], BAYER_PERIOD_PX / np.sqrt(12.0), rtol=0.05)


def test_no_runs_without_a_laser_off_frame_or_along_the_stripe():
    on, off, _, _ = frames(2)
    assert fit_unknown_runs(prepare_image(on, "red", None, None, None, None), True) is None
    # the columns follow this near-vertical stripe lengthwise: its runs are the rows'
    assert fit_unknown_runs(prepare_image(on, "red", off, None, None, None), False) is None


def test_a_glint_clipped_in_every_channel_of_both_frames_is_no_candidate():
    on, off, _, _ = frames(3)
    on[5:12, 10:20] = 255
    off[5:12, 10:20] = 255
    px = unknown_laser(prepare_image(on, "red", off, None, None, None))
    assert not np.any((px.v >= 5) & (px.v < 12) & (px.u >= 10) & (px.u < 20))


@pytest.mark.parametrize("seed", [4, 5])
def test_rank0_follows_the_whitened_beam(seed):
    """Without these candidates the whitened rows have none on the beam (the colour difference dips
    there); with them rank 0 is on it on every row."""
    on, off, centre, whitened = frames(seed)
    t = scanrig.detect_stripe(on, color="red", dark=off)
    u, v, line, rank = (t[k].to_numpy() for k in ("u", "v", "line", "rank"))
    best = (rank == 0) & (v == line)
    found = np.full(SHAPE[0], np.nan)
    found[line[best]] = u[best]
    rows = np.flatnonzero(whitened.any(axis=1))
    assert np.all(np.abs(found[rows] - centre[rows]) <= HALF_STEP_PX)


def test_a_laser_of_another_colour_is_not_whitened():
    """The red frames read as a green laser's: where red clips (outside the rows the camera turns
    white) red rises far past half of green's rise, but blue barely does (its crosstalk); a
    whitened pixel has every other channel risen, so none is found there."""
    on, off, _, _ = frames(0)
    px = unknown_laser(prepare_image(on, "green", off, None, None, None))
    outside = (px.v < WHITENED_ROWS.start) | (px.v >= WHITENED_ROWS.stop)
    assert not outside.any()


def test_a_run_edge_is_known_to_its_pixel_at_worst():
    """On the Ciclop board's glint rows some runs end against a step that barely falls (two runs on
    one row, a clipped neighbour): their σ is bounded by the run's own ends, each within one pixel,
    not blown up by the flat step (it was 1e19 px on two rows)."""
    from tests.laser import ciclop_board

    on, off = ciclop_board.frames()
    fits = fit_unknown_runs(prepare_image(on, "red", off, None, None, None), True)
    assert fits is not None and fits["line"].size >= 60
    worst_var = 0.25 * 2 / 12 + BAYER_PERIOD_PX**2 / 12
    assert np.all(fits["var"] <= worst_var + 1e-12)
