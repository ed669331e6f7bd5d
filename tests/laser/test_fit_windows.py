"""Fit windows end halfway to the neighbouring local maxima of their line, also those the detection
test rejected against the frame's clutter: a stripe's fit does not take in a texture peak beside it."""

import numpy as np

from scanrig.laser import image as image_module
from scanrig.laser.image import prepare_image
from scanrig.laser.peaks import prescan
from scanrig.laser.stripe_candidates import NO_NEIGHBOUR_PX, line_keys, neighbour_gaps, prominent
from scanrig.laser.stripes import _nearest_on_line, detect_stripe
from tests.laser.synth import integrated, quantize

SHAPE = (64, 128)
PAPER_DN = 60.0
NOISE_DN = 2.0
#: The stripe's and the texture peak's heights in red above the paper, DN, and their widths, px:
#: with the clutter at ``CLUTTER_OVER_NOISE`` times the noise the stripe's box sum clears the
#: detection test by about 2x, the texture peak's falls short by about 1.5x and clears the noise's
#: alone by about 5x.
STRIPE_DN, STRIPE_SIGMA_PX = 120.0, 1.2
TEXTURE_DN, TEXTURE_SIGMA_PX = 50.0, 1.0
CLUTTER_OVER_NOISE = 8.0
#: The texture peak's distance from the stripe, px (beyond the 3 px of merging, inside the ±9 px window).
GAP_PX = 5.0
#: A maximum belongs to the stripe or the texture peak within this distance, px.
NEAR_PX = 1.5


def _frame(seed):
    """A red stripe on grey paper and a weaker red texture peak ``GAP_PX`` to its right on every
    row, RGB uint8, and the stripe's centre per row (px)."""
    rng = np.random.default_rng(seed)
    u = np.arange(SHAPE[1], dtype=float)[None, :]
    centre = 60.3 + 0.02 * np.arange(SHAPE[0], dtype=float)[:, None]
    red = (PAPER_DN + STRIPE_DN * integrated(u, centre, STRIPE_SIGMA_PX)
           + TEXTURE_DN * integrated(u, centre + GAP_PX, TEXTURE_SIGMA_PX))
    grey = np.full(SHAPE, PAPER_DN)
    rgb = np.stack([red, grey, grey], axis=-1) + rng.normal(0.0, NOISE_DN, SHAPE + (3,))
    return quantize(rgb), centre[:, 0]


def _row_candidates(image):
    li = prepare_image(image, "red")
    return prominent(li, "rows", prescan(li), 6.0, 3.0, 3.0)


def _clutter(monkeypatch, over_noise):
    monkeypatch.setattr(image_module, "clutter_cells", lambda signal, noise, box_sums=None: over_noise * noise)


def test_a_texture_peak_rejected_against_the_clutter_bounds_the_stripes_window(monkeypatch):
    image, centre = _frame(7)
    _clutter(monkeypatch, 0.0)
    plain = _row_candidates(image)
    texture = np.abs(plain.pos - (centre[plain.line] + GAP_PX)) <= NEAR_PX
    assert np.array_equal(plain.line[texture], np.arange(SHAPE[0]))  # a local maximum above the noise

    _clutter(monkeypatch, CLUTTER_OVER_NOISE)
    cand = _row_candidates(image)
    assert np.array_equal(cand.line, np.arange(SHAPE[0]))  # the stripe alone, once per row
    assert np.all(np.abs(cand.pos - centre) <= NEAR_PX)
    assert np.array_equal(cand.maxima, np.sort(line_keys(plain.line, plain.pos)))  # the rejected kept

    offs = np.arange(-9, 10)
    window = _nearest_on_line(cand.line, cand.pos, cand.maxima, offs)
    gap = plain.pos[texture] - cand.pos  # to the texture peak, px
    assert np.array_equal(window, np.broadcast_to(2 * offs[:, None] < gap, window.shape))  # halfway to it
    assert window[offs <= 0].all()  # nothing bounds it on the left

    t = detect_stripe(image, color="red", direction="rows")
    u, line = t["u"].to_numpy(), t["line"].to_numpy()
    assert np.array_equal(np.unique(line), np.arange(SHAPE[0]))
    assert np.all(np.abs(u - centre[line]) < NEAR_PX)  # the texture peak is not fitted


def test_neighbour_gaps_on_the_same_line_only():
    """Nearest maxima before and after on the same line; one at the position itself is neither."""
    maxima = np.sort(line_keys(np.array([0, 0, 0, 2, 3]), np.array([4, 10, 17, 6, 1])))
    before, after = neighbour_gaps(np.array([0, 0, 1, 2, 3]), np.array([10, 2, 5, 6, 9]), maxima)
    none = NO_NEIGHBOUR_PX
    assert before.tolist() == [6, none, none, none, 8]
    assert after.tolist() == [7, 2, none, none, none]
    empty = neighbour_gaps(np.array([5]), np.array([3]), np.zeros(0, np.int64))
    assert [g.tolist() for g in empty] == [[none], [none]]
