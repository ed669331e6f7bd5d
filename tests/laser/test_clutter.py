"""The detection test against structured clutter: JPEG blocking on flat paper is a floor a stripe's
peak must clear, white noise is not clutter, and the fits keep the noise's σ."""

import numpy as np
import pytest

from scanrig.laser import image as image_module
from scanrig.laser import noise as noise_module
from scanrig.laser.image import prepare_image
from scanrig.laser.noise import clutter_cells
from scanrig.laser.peaks import prescan
from scanrig.laser.stripes import _crossings
from scanrig.sim.colour import colour_frame
from scanrig.sim.sensor import Sensor
from tests.laser.colour_synth import (
    PAPER_LEVEL,
    RESPONSE,
    SLOPE,
    printed_dots,
    stripe_frames,
)
from tests.laser.synth import integrated

#: On white noise the clutter of a cell lies within 6 % of σ (measured on six 1280 × 1024 frames:
#: 0.94-1.05); the median of some 50 interior cells is within about 1 %, and a constant off by 4 % is
#: a calibration error.
CONSTANT_TOL = 0.04
#: Distance from the true stripe within which a candidate is the stripe's (its clipped band and
#: halo), px.
ON_STRIPE_PX = 10
#: A beam within this many pixels of a printed dot is at its edge (the 3-px halo and JPEG's 8-px
#: blocks), px.
INK_REACH_PX = 8


def _candidates(li):
    """The candidates that reach the fit, per scan direction (``detect_stripe``'s defaults)."""
    return _crossings(li, prescan(li), 6.0, 3.0, 3.0)


def _without_clutter(monkeypatch):
    monkeypatch.setattr(image_module, "clutter_cells", lambda signal, noise, box_sums=None: np.zeros_like(noise))


def test_clutter_of_white_noise_is_its_sigma(monkeypatch):
    """The calibration: ungated (every cell above a negligible noise), white noise of σ 1 DN gives
    a clutter of 1 DN."""
    rng = np.random.default_rng(11)
    cells = []
    for _ in range(2):
        signal = rng.normal(0.0, 1.0, (512, 640)).astype(np.float32)
        cells.append(clutter_cells(signal, np.full((8, 10), 1e-6, np.float32))[2:-2, 2:-2])
    assert np.median(cells) == pytest.approx(1.0, rel=CONSTANT_TOL)


def test_white_noise_with_a_stripe_has_no_clutter():
    """Rounded white noise of σ 2 DN and a stripe: no cell's clutter exceeds its noise enough to
    count, so the detection test is the noise's alone (and a grey signal is not asked)."""
    rng = np.random.default_rng(12)
    u = np.arange(640.0)[None, :]
    frame = 20.0 + 300.0 * integrated(u, 300.0 + 0.1 * np.arange(480.0)[:, None], 1.5) + rng.normal(0, 2.0, (480, 640))
    li = prepare_image(np.clip(np.rint(frame), 0, 255).astype(np.uint8))
    assert li.noise_sigma == pytest.approx(2.0, rel=0.1)  # the frame is what the test says it is
    assert not clutter_cells(li.signal, li.noise).any()
    assert not li.clutter.any()


def _texture_and_stripe(found, truth):
    """Candidates off the stripe (count) and the rows holding a row-scanned one on it (set)."""
    texture, on_stripe = 0, set()
    for along, c in found.items():
        u, v = (c.pos, c.line) if along == "rows" else (c.line, c.pos)
        on = np.abs(u - np.interp(v, np.arange(truth.size), truth)) < ON_STRIPE_PX
        texture += int((~on).sum())
        if along == "rows":
            on_stripe |= set(c.line[on].tolist())
    return texture, on_stripe


@pytest.mark.parametrize("with_dark", [False, True])
def test_jpeg_clutter_drops_texture_and_keeps_the_stripe(monkeypatch, with_dark):
    """The rendered printed paper (JPEG 90, 4:2:0): the clutter test removes texture candidates
    (measured on this frame: 975 -> 591 without a laser-off frame, 302 -> 295 with one, whose
    difference leaves peaks of 50-140 DN of box sum, which pass it) and no row of the
    stripe loses its candidate."""
    on, off, truth = stripe_frames(np.random.default_rng(0))
    dark = off if with_dark else None
    li = prepare_image(on, "red", dark)
    assert (li.clutter > li.noise).mean() > 0.5  # clutter above the noise over most of the frame
    texture, stripe_rows = _texture_and_stripe(_candidates(li), truth)
    _without_clutter(monkeypatch)
    texture_before, stripe_rows_before = _texture_and_stripe(_candidates(prepare_image(on, "red", dark)), truth)
    assert stripe_rows == stripe_rows_before
    assert texture < (texture_before if with_dark else 0.7 * texture_before)


def test_candidates_keep_the_noise_sigma():
    """The clutter enters the detection test only: a candidate's noise (the fit's σ) is the noise's."""
    on, _, _ = stripe_frames(np.random.default_rng(1))
    li = prepare_image(on, "red")
    for along, c in _candidates(li).items():
        u, v = (c.pos, c.line) if along == "rows" else (c.line, c.pos)
        assert np.array_equal(c.noise, li.noise_at(u, v).astype(np.float64))
        assert (li.clutter_at(u, v) > c.noise).any()  # where the two differ


def test_two_stripes_close_together_are_not_their_own_clutter(monkeypatch):
    """Two unclipped stripes 40 px apart on printed paper (peak about 0.4 of full scale on paper)
    cross up to half of a 5 × 5 neighbourhood of cells, and JPEG rings beside them: the clutter is
    taken low in the neighbourhood, so on paper both keep every row they had without the clutter
    test. Rows may go only where the beam is on a printed dot or at its edge (20 times dimmer, at
    the level of the texture peaks there)."""
    rng = np.random.default_rng(2)
    shape = (480, 640)
    sensor = Sensor()
    albedo = printed_dots(shape, rng)
    rows = np.arange(shape[0], dtype=float)[:, None]
    centres = [300.0 + SLOPE * rows, 340.0 + SLOPE * rows]
    beam = sum(integrated(np.arange(shape[1], dtype=float)[None, :], c, 1.2) for c in centres)
    scene_e = PAPER_LEVEL * sensor.full_well_e * albedo / albedo.max()
    on = colour_frame(scene_e, 0.4 * sensor.full_well_e * beam, sensor, RESPONSE, rng)
    li = prepare_image(on, "red")
    assert (li.clutter > 0).any()
    found = _candidates(li)
    _without_clutter(monkeypatch)
    found_plain = _candidates(prepare_image(on, "red"))
    for c in centres:
        truth = c[:, 0]
        kept, before = _texture_and_stripe(found, truth)[1], _texture_and_stripe(found_plain, truth)[1]
        assert len(before) > 0.95 * shape[0]  # the stripe is there to lose
        lost = np.array(sorted(before - kept), int)
        near = np.rint(truth[lost, None]).astype(int) + np.arange(-INK_REACH_PX, INK_REACH_PX + 1)
        assert (albedo[lost[:, None], np.clip(near, 0, shape[1] - 1)] < 0.5).any(axis=1).all()


def test_small_frames_have_no_clutter():
    """Too narrow for a maximum's reach on both sides: no clutter, no error."""
    signal = np.random.default_rng(3).normal(0, 1, (40, 2 * noise_module.CLUTTER_REACH_PX + 4)).astype(np.float32)
    noise = np.ones((1, 1), np.float32)
    assert clutter_cells(signal, noise).shape == (1, 1)
    assert not clutter_cells(signal, noise).any()
