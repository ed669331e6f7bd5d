"""The real Ciclop bust frames (tests/data/ciclop-laser-stripes, CC BY-SA 4.0) as other rigs deliver
them: rotated, flipped, down-scaled, cropped to odd sizes, JPEG, 16-bit, grey, RGBA, gamma, swapped
channels; through :func:`scanrig.detect_stripe` and through ``scanrig detect`` on a session folder.

Each variant must put rank 0 on the stripe on the same share of lines as the untransformed frame
(within a margin measured here), or fail with a clear error: never a silent empty or wrong result.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

import scanrig
from scanrig.cli.main import main
from scanrig.errors import InputError, ShapeError
from scanrig.io.session import read_image
from scanrig.laser.clip_level import channel_clip_levels
from tests.data_paths import real_data
from tests.laser.colour_synth import exposed

FOLDER = real_data("ciclop-laser-stripes") / "laser_on_object"
#: The laser is on the bust between these rows of the stored frame (test_laser_ciclop.py).
BUST_ROWS = (41, 1115)
#: Lines where the laser adds this much to the red channel (laser on minus off) carry the stripe, DN.
STRIPE_DN = 60
#: A rank-0 centre this close to its line's strongest red difference is on the stripe, px (full scale).
ON_STRIPE_PX = 6.0
#: Shares measured on 1,031 stripe rows (514 at half scale); baseline 0.9903 without the laser-off
#: frame, 0.9942 with it. Rotated, flipped, cropped to 957 x 1279 and down-scaled frames reach
#: 0.9903-0.9961, so they may lose at most 5 lines in 1,000 ...
GEOMETRIC_MARGIN = 0.005
#: ... JPEG (quality 70-90, 4:2:0 chroma) and gamma 0.8 / 1.25 reach 0.9864-0.9942 (JPEG q80 with
#: the laser-off frame is the lowest: 0.0078 below its baseline): 10 in 1,000.
PHOTOMETRIC_MARGIN = 0.01


def _rot_cw(a):
    return np.ascontiguousarray(np.rot90(a, -1))


def _rot_ccw(a):
    return np.ascontiguousarray(np.rot90(a, 1))


def _flip_lr(a):
    return np.ascontiguousarray(a[:, ::-1])


def _flip_ud(a):
    return np.ascontiguousarray(a[::-1])


def _half(a):
    return cv2.resize(a, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)


def _odd_crop(a):
    """957 x 1279: odd in both directions."""
    return np.ascontiguousarray(a[:1279, :957])


#: name -> (geometric change of an array, image scale, whether the stripe runs along rows
#: afterwards, i.e. is scanned along columns)
GEOMETRIC = {
    "identity": (lambda a: a, 1.0, False),
    "rotated 90 cw": (_rot_cw, 1.0, True),
    "rotated 90 ccw": (_rot_ccw, 1.0, True),
    "flipped left-right": (_flip_lr, 1.0, False),
    "flipped up-down": (_flip_ud, 1.0, False),
    "half scale (INTER_AREA)": (_half, 0.5, False),
    "cropped 957x1279": (_odd_crop, 1.0, False),
}


def jpeg(rgb: np.ndarray, quality: int) -> np.ndarray:
    """``rgb`` (H, W, 3) uint8 through a JPEG of ``quality`` with 4:2:0 chroma, decoded as RGB."""
    ok, data = cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality,
                                                     cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                                                     cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420])
    assert ok
    return np.ascontiguousarray(cv2.imdecode(data, cv2.IMREAD_COLOR)[:, :, ::-1])


def gamma(image: np.ndarray, exponent: float) -> np.ndarray:
    """``image`` uint8 with DN mapped to ``255 (DN / 255) ** exponent``, rounded."""
    lut = np.round(255.0 * (np.arange(256) / 255.0) ** exponent).astype(np.uint8)
    return lut[image]


PHOTOMETRIC = {
    "JPEG q70": lambda a: jpeg(a, 70),
    "JPEG q80": lambda a: jpeg(a, 80),
    "JPEG q90": lambda a: jpeg(a, 90),
    "gamma 0.8": lambda a: gamma(a, 0.8),
    "gamma 1.25": lambda a: gamma(a, 1.25),
}


def grey(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def swapped(rgb: np.ndarray) -> np.ndarray:
    """RGB stored as BGR: the red laser now in the blue channel."""
    return np.ascontiguousarray(rgb[:, :, ::-1])


@pytest.fixture(scope="module")
def frames():
    """The laser-on and laser-off frames, RGB uint8 (960 x 1280)."""
    return read_image(FOLDER / "laser.png"), read_image(FOLDER / "laser_background.png")


@pytest.fixture(scope="module")
def reference(frames):
    """What the laser added to red, ``(H, W)`` float32 DN, and the bust's rows as a float32 mask."""
    on, off = frames
    added = on[:, :, 0].astype(np.float32) - off[:, :, 0]
    bust = np.zeros(added.shape, np.float32)
    bust[BUST_ROWS[0]:BUST_ROWS[1]] = 1.0
    return added, bust


def stripe_share(table, added: np.ndarray, bust: np.ndarray, along_rows: bool = False, scale: float = 1.0
                 ) -> float:
    """Share of the stripe's scan lines whose rank-0 centre is on the stripe.

    Parameters
    ----------
    table : pyarrow.Table
        Detections (``traces.parquet`` columns).
    added, bust : (H, W) float32 arrays
        The red the laser added, DN, and the bust's mask (1 on it), in the detected frame's geometry.
    along_rows : bool
        The stripe runs along rows (scan lines are columns).
    scale : float
        The frame's scale: the on-stripe distance is ``ON_STRIPE_PX * scale``.

    Returns
    -------
    float
        Over the lines on the bust where the laser added more than ``STRIPE_DN``: the share whose
        rank-0 centre on that line is within the distance of the line's largest ``added``.
    """
    u, v, line, rank = (table[k].to_numpy() for k in ("u", "v", "line", "rank"))
    across, on_line, lines_of = (v, u, lambda a: a.T) if along_rows else (u, v, lambda a: a)
    best = (rank == 0) & (on_line == line)
    signal, mask = lines_of(added), lines_of(bust)
    found = np.full(signal.shape[0], np.nan)
    found[line[best]] = across[best]
    peak = np.argmax(signal, axis=1)
    lines = np.flatnonzero((signal.max(axis=1) > STRIPE_DN) & (mask[np.arange(len(peak)), peak] > 0.5))
    assert lines.size > 500 * scale
    return float(np.mean(np.abs(found[lines] - peak[lines]) < ON_STRIPE_PX * scale))


@pytest.fixture(scope="module")
def baseline(frames, reference):
    """Share of the untransformed frame, without and with the laser-off frame: {False: .., True: ..}."""
    on, off = frames
    return {dark: stripe_share(scanrig.detect_stripe(on, color="red", dark=off if dark else None), *reference)
            for dark in (False, True)}


def test_the_untransformed_baseline(baseline):
    """0.9903 and 0.9942 measured; test_laser_ciclop.py requires 0.99."""
    assert baseline[False] >= 0.99 and baseline[True] >= 0.99


@pytest.mark.parametrize("use_dark", [False, True], ids=["no dark", "dark"])
@pytest.mark.parametrize("name", list(GEOMETRIC))
def test_geometric_variants_keep_the_share(frames, reference, baseline, name, use_dark):
    change, scale, along_rows = GEOMETRIC[name]
    on, off = (change(f) for f in frames)
    table = scanrig.detect_stripe(on, color="red", dark=off if use_dark else None)
    added, bust = (change(r) for r in reference)
    assert stripe_share(table, added, bust, along_rows, scale) >= baseline[use_dark] - GEOMETRIC_MARGIN


@pytest.mark.parametrize("use_dark", [False, True], ids=["no dark", "dark"])
@pytest.mark.parametrize("name", list(PHOTOMETRIC))
def test_photometric_variants_keep_the_share(frames, reference, baseline, name, use_dark):
    on, off = (PHOTOMETRIC[name](f) for f in frames)
    table = scanrig.detect_stripe(on, color="red", dark=off if use_dark else None)
    assert stripe_share(table, *reference) >= baseline[use_dark] - PHOTOMETRIC_MARGIN


#: One frame of the pair at another exposure than the other (automatic exposure or white balance):
#: (gain of the laser-on frame, gain of the laser-off frame), DN times the gain, clipped pixels
#: still clipped. Measured 0.9913-0.9942 with the laser-off frame matched (before: 0.9670 and
#: 0.9709 with the laser-off frame at x 0.7 and x 0.8).
EXPOSURE = {"laser-off frame x0.7": (1.0, 0.7), "laser-off frame x0.8": (1.0, 0.8), "laser-off frame x1.5": (1.0, 1.5),
            "laser-on frame x0.8": (0.8, 1.0), "laser-on frame x1.25": (1.25, 1.0)}


@pytest.mark.parametrize("name", list(EXPOSURE))
def test_frames_at_two_exposures_keep_the_share(frames, reference, baseline, name):
    on, off = (exposed(f, gain) for f, gain in zip(frames, EXPOSURE[name]))
    table = scanrig.detect_stripe(on, color="red", dark=off)
    assert stripe_share(table, *reference) >= baseline[True] - PHOTOMETRIC_MARGIN


#: Flicker bands on one frame of the pair (a rolling shutter under a flickering lamp): each row's
#: gain 1 + 0.2 sin(2π row / period + 0.7). Measured 0.9913-0.9922 on the laser-off frame (before
#: it was matched row by row: 0.9884-0.9893) and 0.9884-0.9922 on the laser-on frame (0.9903-0.9922).
FLICKER = {f"laser-{which} frame, ±20 % over {period} rows": (which, period) for which in ("off", "on")
           for period in (300, 700)}


@pytest.mark.parametrize("name", list(FLICKER))
def test_flicker_bands_keep_the_share(frames, reference, baseline, name):
    which, period = FLICKER[name]
    rows = np.arange(frames[0].shape[0])
    bands = (1.0 + 0.2 * np.sin(2.0 * np.pi * rows / period + 0.7))[:, None, None]
    on, off = (frames[0], exposed(frames[1], bands)) if which == "off" else (exposed(frames[0], bands), frames[1])
    table = scanrig.detect_stripe(on, color="red", dark=off)
    assert stripe_share(table, *reference) >= baseline[True] - PHOTOMETRIC_MARGIN


def _rank0(table) -> np.ndarray:
    """``(u, sigma_px)`` of each frame row's rank-0 row-scanned centre, ``(H, 2)``, NaN where none."""
    u, v, line, rank, sigma = (table[k].to_numpy() for k in ("u", "v", "line", "rank", "sigma_px"))
    best = (rank == 0) & (v == line)
    out = np.full((int(line.max()) + 1 if len(line) else 0, 2), np.nan)
    out[line[best]] = np.c_[u, sigma][best]
    return out


#: On the bust's rows the 16-bit frames' rank-0 centres agree with the 8-bit frame's to 0.0141 px
#: (measured with the laser-off frame; 0.0066 px without), their sigmas to 0.0037 px at the 99th
#: percentile (one row without the laser-off frame: 0.126 px): the noise estimate's quantisation
#: term is 257 times smaller. Without the laser-off frame one bust row (253) of the 1,074 has a
#: rank-0 centre in the 8-bit frame only. The same holds for 12-bit data (x 16) with the found
#: clip level.
SIXTEEN_BIT_PX = 0.02
SIXTEEN_BIT_SIGMA_P99_PX = 0.01
SIXTEEN_BIT_ROWS_APART = 2


def assert_same_bust_centres(found: np.ndarray, expected: np.ndarray) -> None:
    """On the bust's rows: a rank-0 centre in the same rows but ``SIXTEEN_BIT_ROWS_APART``, and
    where both have one, the centres and sigmas within the limits above."""
    found, expected = found[slice(*BUST_ROWS)], expected[slice(*BUST_ROWS)]
    assert np.sum(np.isnan(found[:, 0]) != np.isnan(expected[:, 0])) <= SIXTEEN_BIT_ROWS_APART
    both = ~np.isnan(found[:, 0]) & ~np.isnan(expected[:, 0])
    np.testing.assert_allclose(found[both, 0], expected[both, 0], rtol=0, atol=SIXTEEN_BIT_PX)
    assert np.percentile(np.abs(found[both, 1] - expected[both, 1]), 99) <= SIXTEEN_BIT_SIGMA_P99_PX


@pytest.mark.parametrize("use_dark", [False, True], ids=["no dark", "dark"])
def test_16_bit_frames_give_the_8_bit_centres(frames, reference, baseline, use_dark):
    """Values x 257 (the 16-bit file of an 8-bit frame): the same share and, on the bust, the same
    centres. (Below the bust, on the turntable, the 16-bit frame has 3-9 more rows with a candidate,
    and without the laser-off frame two of them rank another peak 6.6 px away.)"""
    on, off = frames
    dark8, dark16 = (off, off.astype(np.uint16) * 257) if use_dark else (None, None)
    sixteen = scanrig.detect_stripe(on.astype(np.uint16) * 257, color="red", dark=dark16)
    assert stripe_share(sixteen, *reference) == baseline[use_dark]
    assert_same_bust_centres(_rank0(sixteen), _rank0(scanrig.detect_stripe(on, color="red", dark=dark8)))


def test_12_bit_data_in_16_bit_frames_need_the_found_clip_level(frames):
    """A 12-bit camera's 16-bit files (values x 16) clip at 4,080, not 65,535: with
    ``saturation_level="auto"`` the centres are the 8-bit frame's. (With the dtype's maximum the
    clipped core is fitted as a peak: the share drops to 0.954 and rank-0 centres move by up to
    3.9 px, 99th percentile; ``scanrig detect`` has no way to say so: see the CLI test below.)"""
    on, off = frames
    eight = scanrig.detect_stripe(on, color="red", dark=off, saturation_level="auto")
    twelve = scanrig.detect_stripe(on.astype(np.uint16) * 16, color="red", dark=off.astype(np.uint16) * 16,
                                   saturation_level="auto")
    assert_same_bust_centres(_rank0(twelve), _rank0(eight))


def test_grey_frames_with_dark_reach_what_their_luma_carries(frames, reference):
    """The webcam lowers green by 49 DN under the red beam (median), so the luma of the stripe is 16
    DN where red gains 160: in 4.8 % of the stripe's rows the luma difference peaks 6 px or more
    from the red one. The detector on the grey frames (0.965 measured) must do at least as well as
    that peak (0.952)."""
    on, off = (grey(f) for f in frames)
    added, bust = reference
    luma_added = on.astype(np.float32) - off
    rows = np.flatnonzero((added.max(axis=1) > STRIPE_DN) & (bust[:, 0] > 0.5))
    red_peak = np.argmax(added[rows], axis=1)
    window = np.clip(red_peak[:, None] + np.arange(-15, 16), 0, added.shape[1] - 1)
    luma_peak = window[np.arange(len(rows)), np.argmax(luma_added[rows[:, None], window], axis=1)]
    luma_share = np.mean(np.abs(luma_peak - red_peak) < ON_STRIPE_PX)
    share = stripe_share(scanrig.detect_stripe(on, color="grey", dark=off), added, bust)
    assert share >= luma_share


def test_grey_frames_without_dark(frames, reference):
    """Without the laser-off frame the 16 DN luma stripe competes with the bust's shading: 0.838
    measured (the colour frame: 0.990). A limit of the data (a colour webcam's frame made grey),
    pinned here so that a change is seen."""
    share = stripe_share(scanrig.detect_stripe(grey(frames[0]), color="grey"), *reference)
    assert share >= 0.83


def test_a_grey_frame_with_a_colour_laser_is_detected_as_grey(frames):
    """A grey camera with a red laser (``laser_color = "red"`` kept from a colour rig): the frame is
    the laser's signal; the same detections as with ``color="grey"``."""
    on, off = (grey(f) for f in frames)
    as_red = _rank0(scanrig.detect_stripe(on, color="red", dark=off))
    np.testing.assert_allclose(as_red, _rank0(scanrig.detect_stripe(on, color="grey", dark=off)), rtol=1e-9)


def test_swapped_channels_with_the_matching_colour_are_the_same_detection(frames):
    """BGR data with ``color="blue"`` names the same channel: the same detections."""
    on, off = frames
    np.testing.assert_allclose(_rank0(scanrig.detect_stripe(swapped(on), color="blue", dark=swapped(off))),
                               _rank0(scanrig.detect_stripe(on, color="red", dark=off)), rtol=1e-9)


def test_an_rgba_array_is_refused_with_its_shape(frames):
    rgba = np.dstack([frames[0], np.full(frames[0].shape[:2], 255, np.uint8)])
    with pytest.raises(ShapeError, match=r"\(H, W\) or \(H, W, 3\), got \(1280, 960, 4\)"):
        scanrig.detect_stripe(rgba, color="red")


def _wrong_colour_handled(call, reference, baseline) -> None:
    """``call()`` either raises an error that names the colour the frame shows (blue), or returns
    detections with the baseline's share."""
    try:
        table = call()
    except ValueError as exc:
        assert "blue" in str(exc)
        return
    assert stripe_share(table, *reference) >= baseline - PHOTOMETRIC_MARGIN


@pytest.mark.parametrize("use_dark", [False, True], ids=["no dark", "dark"])
def test_swapped_channels_with_the_wrong_colour_say_so(frames, reference, baseline, use_dark):
    """BGR frames with ``color="red"`` (the laser in the blue channel). Before: with the laser-off
    frame 0 candidates and no error; without it 254 candidates and rank 0 on the stripe in 0 of
    1,031 rows."""
    on, off = (swapped(f) for f in frames)
    _wrong_colour_handled(lambda: scanrig.detect_stripe(on, color="red", dark=off if use_dark else None),
                          reference, baseline[use_dark])


@pytest.mark.parametrize("use_dark", [False, True], ids=["no dark", "dark"])
def test_the_wrong_colour_error_names_the_argument_and_the_channel(frames, use_dark):
    on, off = (swapped(f) for f in frames)
    with pytest.raises(InputError, match=r"^color='red': no red laser in this frame; its blue channel shows one "
                                         r"\(\d+ DN of laser light\): use color='blue' \(red and blue are swapped "
                                         r"where RGB data were stored as BGR\)$"):
        scanrig.detect_stripe(on, color="red", dark=off if use_dark else None)


PATTERN = real_data("ciclop-laser-stripes") / "laser_on_pattern"


@pytest.mark.parametrize("use_dark", [False, True], ids=["no dark", "dark"])
@pytest.mark.parametrize("name", ["laser-0-255-255-8", "laser-0-255-255-8-x"])
def test_the_right_colour_on_the_board_is_not_questioned(name, use_dark):
    """The board's two stripe frames with ``color="red"``: detected, no error (red's rank-0 peaks
    reach half the clip level on 548-565 lines; blue's and green's on 95 at most)."""
    on = read_image(PATTERN / f"{name}.png")
    dark = read_image(PATTERN / f"{name.replace('laser-', 'laser-background-', 1)}.png") if use_dark else None
    assert len(scanrig.detect_stripe(on, color="red", dark=dark)) > 0


@pytest.mark.parametrize("color", ["green", "blue"])
@pytest.mark.parametrize("path", [FOLDER / "laser_background.png", FOLDER / "texture.png", PATTERN / "pattern.png"],
                         ids=["bust, laser off", "bust, texture", "board, laser off"])
def test_frames_without_the_laser_name_no_colour(path, color):
    """The Ciclop's frames without the laser, asked for a green or blue one: the scene's warm
    colours and printed texture find more red than green or blue, but no candidate bright enough
    to be a laser (half the clip level on 2 lines at most), so no colour is named."""
    scanrig.detect_stripe(read_image(path), color=color)


def test_grey_in_three_channels_with_a_colour_laser_is_the_grey_frame(frames, reference):
    """A grey frame stored in three equal channels (GRAY2RGB), ``color="red"``: the detections of the
    2-D grey frame (share 0.965). Before, red minus the others was 0: rank 0 on the stripe in 0.097
    of the rows."""
    grey_frames = [grey(f) for f in frames]
    on, off = (cv2.cvtColor(f, cv2.COLOR_GRAY2RGB) for f in grey_frames)
    table = scanrig.detect_stripe(on, color="red", dark=off)
    assert table.equals(scanrig.detect_stripe(grey_frames[0], color="red", dark=grey_frames[1]))
    assert stripe_share(table, *reference) >= 0.96


# --- scanrig detect on a session folder --------------------------------------------------------


def write_frame(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB(A) or grey array as a rig would: JPEG at quality 80 with 4:2:0 chroma."""
    if rgb.ndim == 3:
        rgb = rgb[:, :, [2, 1, 0, 3][: rgb.shape[2]]]
    params = [cv2.IMWRITE_JPEG_QUALITY, 80, cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
              cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420] if path.suffix == ".jpg" else []
    assert cv2.imwrite(str(path), rgb, params)


def detect_cli(root: Path, on: np.ndarray, off: np.ndarray | None, suffix: str, color: str | None = "red") -> int:
    """``scanrig detect`` on a session of one camera: ``scan/cam0/00000<suffix>`` and its ``dark``
    (none when ``off`` is None), ``laser_color`` ``color`` (none when None)."""
    folder = root / "scan" / "cam0"
    folder.mkdir(parents=True, exist_ok=True)
    write_frame(folder / f"00000{suffix}", on)
    if off is not None:
        write_frame(folder / f"dark{suffix}", off)
    colour_line = "" if color is None else f'laser_color = "{color}"\n'
    (root / "session.toml").write_text('laser_mode = "stripe"\n' + colour_line)
    return main(["detect", str(root)])


def _rgba(rgb):
    return np.dstack([rgb, np.full(rgb.shape[:2], 255, rgb.dtype)])


def _sixteen(rgb):
    return rgb.astype(np.uint16) * 257


def _red_gain(rgb):
    """Red times 235/255, rounded: a white balance gain below 1 applied after the sensor clipped, so
    that red clips at 235 DN."""
    out = rgb.copy()
    out[:, :, 0] = np.round(rgb[:, :, 0] * (235.0 / 255.0))
    return out


#: name -> (change of the frames, file suffix, geometric change of the reference, stripe along
#: rows, scale, margin). Measured shares: all 0.9942 (the library's with its laser-off frame)
#: but JPEG q80 0.9864, the half-scale frame 0.9961, red clipped at 235 0.9932 (0.9544 when the
#: session's default was the dtype's maximum), and grey (below).
SESSIONS = {
    "PNG": (lambda a: a, ".png", lambda a: a, False, 1.0, GEOMETRIC_MARGIN),
    "PNG rotated 90 cw": (_rot_cw, ".png", _rot_cw, True, 1.0, GEOMETRIC_MARGIN),
    "PNG half scale": (_half, ".png", _half, False, 0.5, GEOMETRIC_MARGIN),
    "PNG cropped 957x1279": (_odd_crop, ".png", _odd_crop, False, 1.0, GEOMETRIC_MARGIN),
    "JPEG q80 4:2:0": (lambda a: a, ".jpg", lambda a: a, False, 1.0, PHOTOMETRIC_MARGIN),
    "16-bit PNG": (_sixteen, ".png", lambda a: a, False, 1.0, GEOMETRIC_MARGIN),
    "16-bit TIFF": (_sixteen, ".tif", lambda a: a, False, 1.0, GEOMETRIC_MARGIN),
    "RGBA PNG": (_rgba, ".png", lambda a: a, False, 1.0, GEOMETRIC_MARGIN),
    "BMP": (lambda a: a, ".bmp", lambda a: a, False, 1.0, GEOMETRIC_MARGIN),
    "16-bit PPM": (_sixteen, ".ppm", lambda a: a, False, 1.0, GEOMETRIC_MARGIN),
    "red clipped at 235": (_red_gain, ".png", lambda a: a, False, 1.0, GEOMETRIC_MARGIN),
}


@pytest.mark.parametrize("name", list(SESSIONS))
def test_detect_verb_on_session_variants(tmp_path, frames, reference, baseline, name):
    change, suffix, geometry, along_rows, scale, margin = SESSIONS[name]
    assert detect_cli(tmp_path, *(change(f) for f in frames), suffix) == 0
    table = pq.read_table(tmp_path / "traces.parquet")
    added, bust = (geometry(r) for r in reference)
    assert stripe_share(table, added, bust, along_rows, scale) >= baseline[True] - margin


#: name -> (the frames of red clipped at 235 as stored: JPEG quality, file suffix; whether the
#: laser-off frame is given). Measured shares: 0.9884-0.9942 (quality 95, 90, 80, 70, with and
#: without the laser-off frame); 0.930-0.977 when the level was not found.
CLIPPED_JPEG = {"JPEG q80 files": (None, ".jpg", True), "JPEG q80 files, no laser-off frame": (None, ".jpg", False),
                "JPEG q95": (95, ".png", True), "JPEG q70": (70, ".png", True)}


@pytest.mark.parametrize("name", list(CLIPPED_JPEG))
def test_a_jpeg_channel_clipped_below_255_is_found_from_the_lasers_peaks(tmp_path, frames, reference, baseline, name):
    """Red clipping at 235 DN (white balance), stored as JPEG (4:2:0): the plateau is spread over
    some 15 values and piles up on none, so the level is read from the laser's peaks along the
    rows (:func:`scanrig.laser.clip_level.channel_clip_levels`); the bust's share is then the
    PNG's."""
    quality, suffix, with_dark = CLIPPED_JPEG[name]
    on, off = (_red_gain(f) if quality is None else jpeg(_red_gain(f), quality) for f in frames)
    assert detect_cli(tmp_path, on, off if with_dark else None, suffix) == 0
    assert stripe_share(pq.read_table(tmp_path / "traces.parquet"), *reference) >= baseline[True] - PHOTOMETRIC_MARGIN


def test_the_clip_level_found_in_jpeg_frames_is_below_the_plateaus_median(frames):
    """The level read from the peaks of red clipped at 235 DN, stored as JPEG: 232-233 DN measured
    (the plateau's lower quartile), with and without the laser-off frame; the frames as they are
    (clipped at 255) keep 255."""
    for quality in (95, 80, 70):
        on, off = (jpeg(_red_gain(f), quality) for f in frames)
        for dark in (off, None):
            assert 228 <= channel_clip_levels(on, dark, laser_channel=0)[0] <= 236
        assert channel_clip_levels(*(jpeg(f, quality) for f in frames), laser_channel=0)[0] == 255


def test_detect_verb_on_grey_frames_with_a_red_laser(tmp_path, frames, reference):
    """Grey PNGs, ``laser_color = "red"``: as the library on the grey frames (0.9651 measured)."""
    assert detect_cli(tmp_path, *(grey(f) for f in frames), ".png") == 0
    assert stripe_share(pq.read_table(tmp_path / "traces.parquet"), *reference) >= 0.96


def test_detect_verb_on_swapped_channels_says_which_colour(tmp_path, frames, capsys):
    """PNGs written from RGB arrays by cv2.imwrite (red and blue swapped), ``laser_color = "red"``:
    one line naming the camera, its frame and the colour the frames show, and exit 2 with nothing
    written (nothing was detected). Before: exit 0, "0 candidates in 1 camera frames" and an empty
    traces.parquet."""
    assert detect_cli(tmp_path, *(swapped(f) for f in frames), ".png") == 2
    assert capsys.readouterr().err.splitlines() == [
        f"warning: cam0: no red laser in {tmp_path / 'scan' / 'cam0' / '00000.png'}; the frames show a blue one: "
        "use --color blue (or laser_color = 'blue' in session.toml)",
        f"error: {tmp_path / 'scan'}: no red laser stripe in any of 1 camera frames; traces.parquet not written"]
    assert not (tmp_path / "traces.parquet").exists()


def test_detect_verb_on_swapped_channels_without_the_laser_off_frame(tmp_path, frames, capsys):
    """Without ``dark.png`` red finds texture (254 candidates, none on the stripe, none of half the
    clip level, as the detectors' own check counts laser light): exit 0, and the line names blue."""
    assert detect_cli(tmp_path, *(swapped(f) for f in frames), ".png") == 2
    (tmp_path / "scan" / "cam0" / "dark.png").unlink()
    capsys.readouterr()
    assert main(["detect", str(tmp_path)]) == 0
    assert capsys.readouterr().err.splitlines() == [
        f"warning: cam0: no red laser in {tmp_path / 'scan' / 'cam0' / '00000.png'}; the frames show a blue one: use "
        "--color blue (or laser_color = 'blue' in session.toml)"]


def test_detect_verb_without_a_laser_colour_names_the_lasers(tmp_path, frames, reference, capsys):
    """The real frames with no ``laser_color`` (grey, the frames' luma): with the laser-off frame
    grey's rank-0 peaks sum to a quarter of red's, so the line names red (rank 0 on the stripe on
    0.904 of rows as grey, 0.994 as red)."""
    capsys.readouterr()
    assert detect_cli(tmp_path, *frames, ".png", color=None) == 0
    assert capsys.readouterr().err.splitlines() == [
        f"warning: cam0: grey finds 4 times less laser light than red in {tmp_path / 'scan' / 'cam0' / '00000.png'}; "
        "the frames show a red one: use --color red (or laser_color = 'red' in session.toml)"]
    assert stripe_share(pq.read_table(tmp_path / "traces.parquet"), *reference) < 0.95


def test_detect_verb_on_the_right_colour_names_no_other(tmp_path, frames, capsys):
    """The real frames with ``laser_color = "red"``: no line about colours (blue and green find
    1/181 and less of red's laser light with the laser-off frame, 1/18 without)."""
    assert detect_cli(tmp_path, *frames, ".png") == 0
    assert capsys.readouterr().err == ""


def test_detect_verb_on_grey_frames_in_three_channels_with_a_red_laser(tmp_path, frames, reference):
    """Grey frames stored as three equal channels (GRAY2RGB), ``laser_color = "red"``: detected as
    the grey frames they are (0.9651, as the 2-D grey PNGs). Before: red minus the others is 0
    and rank 0 was on the stripe in 0.097 of the rows."""
    assert detect_cli(tmp_path, *(cv2.cvtColor(grey(f), cv2.COLOR_GRAY2RGB) for f in frames), ".png") == 0
    assert read_image(tmp_path / "scan" / "cam0" / "00000.png").shape == frames[0].shape
    assert stripe_share(pq.read_table(tmp_path / "traces.parquet"), *reference) >= 0.96


def test_detect_verb_on_12_bit_data_in_16_bit_files(tmp_path, frames, reference, baseline):
    """16-bit PNGs of a 12-bit camera (values x 16, red clips at 4,080): the clip level of 16-bit
    frames is found from the data by default, so the share is the 8-bit frame's (before, with
    65535: 0.954, and rank-0 centres 3.9 px away at the 99th percentile)."""
    assert detect_cli(tmp_path, *(f.astype(np.uint16) * 16 for f in frames), ".png") == 0
    share = stripe_share(pq.read_table(tmp_path / "traces.parquet"), *reference)
    assert share >= baseline[True] - GEOMETRIC_MARGIN


def test_detect_verb_saturation_level_option(tmp_path, frames, reference, baseline, capsys):
    """``--saturation-level 4080`` on the same files: the same detections as the found level (red
    clips at 4,080, green and blue never reach it); 65535 gives back the clipped core fitted as a
    peak (share 0.954 measured)."""
    assert detect_cli(tmp_path, *(f.astype(np.uint16) * 16 for f in frames), ".png") == 0
    found = pq.read_table(tmp_path / "traces.parquet")
    assert main(["detect", str(tmp_path), "--saturation-level", "4080"]) == 0
    assert pq.read_table(tmp_path / "traces.parquet").equals(found)
    assert main(["detect", str(tmp_path), "--saturation-level", "65535"]) == 0
    assert stripe_share(pq.read_table(tmp_path / "traces.parquet"), *reference) < baseline[True] - 0.03


def test_detect_verb_on_frames_in_a_format_it_does_not_read(tmp_path, frames, capsys):
    """A camera raw file among PNG frames: one error line naming it and the formats read, exit 2,
    nothing written; not a frame silently left out."""
    raw = tmp_path / "scan" / "cam0" / "00001.nef"
    raw.parent.mkdir(parents=True)
    raw.write_bytes(b"MM\x00* a camera raw file")
    assert detect_cli(tmp_path, *frames, ".png") == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith(f"error: {raw}: ")
    assert ".png" in errors[0] and not (tmp_path / "traces.parquet").exists()


def test_detect_verb_on_grey_and_alpha_pngs_with_a_red_laser(tmp_path, frames, reference):
    """Grey PNGs with an alpha channel (PNG colour type 4), ``laser_color = "red"``: read as stored,
    grey, so as the grey PNGs (0.9651). Before, read as three equal colour channels: red minus the
    others is 0 and rank 0 was on the stripe in 0.097 of the rows."""
    from PIL import Image

    folder = tmp_path / "scan" / "cam0"
    folder.mkdir(parents=True)
    for name, frame in zip(("00000", "dark"), frames):
        Image.fromarray(grey(frame), "L").convert("LA").save(folder / f"{name}.png")
    assert read_image(folder / "dark.png").shape == frames[1].shape[:2]
    (tmp_path / "session.toml").write_text('laser_mode = "stripe"\nlaser_color = "red"\n')
    assert main(["detect", str(tmp_path)]) == 0
    assert stripe_share(pq.read_table(tmp_path / "traces.parquet"), *reference) >= 0.96
