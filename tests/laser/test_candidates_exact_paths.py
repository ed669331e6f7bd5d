"""The fast paths of candidate finding give exactly what their plain formulations give.

The clip mask compares integers, the correlated-noise median comes from a histogram, a clipped
run's ends from the first unclipped pixel, the clutter's quantiles from one sort, and the luma
difference's noise line from NumPy's sums: each is checked against the obvious computation, on
the inputs where a shortcut could slip (levels between integers, ties, runs at the frame's edge).
"""

import numpy as np
import pytest

from scanrig.laser.image import _clipped
from scanrig.laser.luma import _variance_line
from scanrig.laser.noise import (
    _CLUTTER_BINS,
    _CLUTTER_CLIP,
    _CLUTTER_MIN_MAXIMA,
    _CLUTTER_QUANTILE,
    _CLUTTER_RANK,
    _CLUTTER_ROW_STEP,
    _CLUTTER_SPAN,
    _CLUTTER_WHITE,
    _HISTOGRAM_MAX,
    CLUTTER_MIN,
    CLUTTER_REACH_PX,
    NOISE_CELL,
    _middle_value,
    clutter_cells,
    correlated_noise_factor,
    high_pass_bands,
)
from scanrig.laser.pixels import padded_box_sums
from scanrig.laser.stripe_candidates import _centre_of_saturated_run, leading_true


@pytest.mark.parametrize("values", [
    np.r_[np.zeros(700, np.int32), np.arange(1, 301, dtype=np.int32)],  # most equal, as in flat JPEG areas
    np.repeat(np.arange(4), 5),  # the middle one is the first of a value
    np.random.default_rng(1).integers(0, 40, 1001).astype(np.int32),
    np.random.default_rng(2).integers(0, 4 * _HISTOGRAM_MAX, 999),  # beyond the histogram: a selection
    np.random.default_rng(3).integers(-5, 5, 100),  # negative: a selection
    np.random.default_rng(4).random(50).astype(np.float32),
])
def test_middle_value_is_that_of_a_selection(values):
    middle = values.size // 2
    assert _middle_value(values) == np.partition(values, middle)[middle]


def _jpeg_like(rng, shape) -> np.ndarray:
    """A colour difference with flat blocks (most high-pass values zero) and some noise, DN."""
    blocks = np.repeat(np.repeat(rng.integers(-4, 5, (shape[0] // 8, shape[1] // 8)), 8, 0), 8, 1)
    return blocks + rng.integers(-1, 2, shape) * (rng.random(shape) < 0.3)


def test_correlated_noise_factor_of_half_integers_is_that_of_the_doubled_integers():
    """A colour difference (multiples of ½ DN, float32) has the factor of twice itself as integers,
    with twice the σ: both medians come from the histogram, one through the float path."""
    rng = np.random.default_rng(5)
    doubled = _jpeg_like(rng, (96, 200)) + 10  # integers, positive
    half = (doubled / 2.0).astype(np.float32)
    rows, _ = high_pass_bands(half)
    factor = correlated_noise_factor(half, rows, 0.3)
    assert factor > 1.0  # the test compares a measured factor, not the floor of 1
    assert factor == correlated_noise_factor(doubled.astype(np.uint16), rows, 0.6)


def test_correlated_noise_factor_of_other_floats_is_that_of_the_scaled_integers():
    """Quarter-DN values are no multiples of ½ DN: their median comes from a selection of floats."""
    rng = np.random.default_rng(6)
    quadrupled = _jpeg_like(rng, (96, 200)) * 3 + 1 + 20
    quarter = (quadrupled / 4.0).astype(np.float32)
    rows, _ = high_pass_bands(quarter)
    factor = correlated_noise_factor(quarter, rows, 0.2)
    assert factor > 1.0
    assert factor == pytest.approx(correlated_noise_factor(quadrupled.astype(np.uint16), rows, 0.8), rel=1e-12)


@pytest.mark.parametrize("dtype, levels", [(np.uint8, [247.35, 200.0, 180.5]), (np.uint16, [63569.9, 65535.0, 4095.0])])
@pytest.mark.parametrize("color", ["grey", "red", "green", "blue"])
def test_clip_mask_of_integer_comparisons_is_that_of_float_comparisons(dtype, levels, color):
    rng = np.random.default_rng(7)
    top = np.iinfo(dtype).max
    levels = np.array(levels)
    image = rng.integers(0, top, (40, 50, 3), endpoint=True).astype(dtype)
    image[5:9, 5:9] = np.floor(levels).astype(dtype)  # at the levels' integer parts: below a fractional level
    image[20:22, :] = np.ceil(levels).astype(dtype)  # at their ceilings: at or above
    channel = {"red": 0, "green": 1, "blue": 2}.get(color)
    expected = (image >= levels).any(axis=2) if channel is None else image[:, :, channel] >= levels[channel]
    np.testing.assert_array_equal(_clipped(image, color, levels), expected)
    grey = image[:, :, 0]
    np.testing.assert_array_equal(_clipped(grey, "grey", levels[:1]), grey >= levels[0])


def test_no_clip_mask_where_nothing_reaches_the_level():
    image = np.full((10, 12, 3), 100, np.uint8)
    assert _clipped(image, "red", np.array([100.5, 0.0, 0.0])) is None


def test_leading_true_counts_the_first_run():
    rng = np.random.default_rng(8)
    a = rng.random((300, 9)) < 0.7
    a[0], a[1] = True, False  # all True, all False
    expected = np.cumprod(a, axis=1).sum(axis=1)
    np.testing.assert_array_equal(leading_true(a), expected)
    assert leading_true(a)[0] == 9 and leading_true(a)[1] == 0


@pytest.mark.parametrize("transposed", [False, True])
def test_clipped_runs_are_centred_up_to_the_frame_edge(transposed):
    """Runs inside the frame, touching its edges and longer than the reach, against a plain loop."""
    rng = np.random.default_rng(9)
    saturated = np.zeros((30, 40), bool)
    for row in range(30):
        a, length = rng.integers(-5, 40), rng.integers(1, 15)
        saturated[row, max(a, 0) : max(a + length, 0)] = True
    saturated[3] = True  # the whole line
    if transposed:
        saturated = np.ascontiguousarray(saturated.T).T  # as columns are scanned: a transposed view
    line, pos = np.nonzero(saturated)
    clipped = np.ones(line.size, bool)
    clipped[::3] = False  # seeds off the run stay where they are
    reach = 6
    centre, run_half = _centre_of_saturated_run(saturated, line, pos, clipped, reach)
    for k in range(line.size):
        if not clipped[k]:
            assert (centre[k], run_half[k]) == (pos[k], 0)
            continue
        right = left = 0
        while right < reach and pos[k] + right + 1 < saturated.shape[1] and saturated[line[k], pos[k] + right + 1]:
            right += 1
        while left < reach and pos[k] - left - 1 >= 0 and saturated[line[k], pos[k] - left - 1]:
            left += 1
        # the seed itself counts on both sides
        assert centre[k] == pos[k] + (right - left) // 2
        assert run_half[k] == (right + 1 + left + 1) // 2


def _plain_clutter(signal: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray, float]:
    """:func:`clutter_cells` computed maximum by maximum and cell by cell, and the clip level (DN of
    the box sum)."""
    h, w = signal.shape
    reach, hc, wc = CLUTTER_REACH_PX, noise.shape[0], noise.shape[1]
    found = []  # (cell row, cell column, prominence)
    for row in range(1, h - 1, _CLUTTER_ROW_STEP):
        box = {x: float(signal[row - 1 : row + 2, x - 1 : x + 2].astype(np.float64).sum()) for x in range(1, w - 1)}
        for x in range(reach + 1, w - reach - 1):
            if box[x] >= box[x - 1] and box[x] > box[x + 1]:
                left = min(box[x - k] for k in range(1, reach + 1))
                right = min(box[x + k] for k in range(1, reach + 1))
                found.append((row // NOISE_CELL, x // NOISE_CELL, max(box[x] - max(left, right), 0.0)))
    prominence = np.array([p for _, _, p in found])
    clip = _CLUTTER_CLIP * np.quantile(prominence, _CLUTTER_QUANTILE)
    level = np.zeros((hc, wc))
    for i in range(hc):
        for j in range(wc):
            values = np.sort([p for a, b, p in found if (a, b) == (i, j) and p <= clip])
            if values.size >= _CLUTTER_MIN_MAXIMA:
                level[i, j] = values[int(np.floor(_CLUTTER_QUANTILE * (values.size - 1)))]
    level = level.astype(np.float32) / np.float32(3.0 * _CLUTTER_WHITE)  # in float32, as the detector
    low = np.zeros_like(level)
    r = _CLUTTER_SPAN // 2
    for i in range(hc):
        for j in range(wc):
            around = [level[min(max(a, 0), hc - 1), min(max(b, 0), wc - 1)]
                      for a in range(i - r, i + r + 1) for b in range(j - r, j + r + 1)]
            low[i, j] = np.sort(around)[_CLUTTER_RANK]
    return np.where(low >= CLUTTER_MIN * noise, low, np.float32(0.0)), clip


@pytest.mark.parametrize("as_half_integers", [False, True])
@pytest.mark.parametrize("scale", [1, 8])
def test_clutter_cells_are_those_of_the_plain_computation(as_half_integers, scale):
    """Histograms of the cells' maxima and a stacked partition over cells give each cell's quantile
    and rank to within one of the ``_CLUTTER_BINS`` bins of the clip level (the bins' lower edges),
    for 8-bit data and a colour difference's half-integers, small and large prominences."""
    rng = np.random.default_rng(7)
    values = _jpeg_like(rng, (200, 336)) * scale + rng.integers(0, 3, (200, 336)) + 40
    signal = (values / 2.0).astype(np.float32) if as_half_integers else values.astype(np.uint8)
    noise = np.full((4, 6), 1e-3, np.float32)  # far below the clutter: no cell near the noise's gate
    noise[0, 0] = 500.0  # ... but this one, whose noise hides its clutter
    fast, (plain, clip) = clutter_cells(signal, noise), _plain_clutter(signal, noise)
    assert fast.any() and not fast[0, 0]
    bin_width = clip / _CLUTTER_BINS / (3.0 * _CLUTTER_WHITE)
    assert np.all((fast <= plain) & (fast >= plain - bin_width))


@pytest.mark.parametrize("as_half_integers", [False, True])
def test_clutter_cells_from_the_frames_box_sums_are_those_from_the_signal(as_half_integers):
    rng = np.random.default_rng(9)
    values = _jpeg_like(rng, (200, 336)) + rng.integers(0, 3, (200, 336)) + 40
    signal = (values / 2.0).astype(np.float32) if as_half_integers else values.astype(np.uint8)
    noise = np.full((4, 6), 1e-3, np.float32)
    summed = clutter_cells(signal, noise)
    assert summed.any()
    np.testing.assert_array_equal(clutter_cells(signal, noise, padded_box_sums(signal)), summed)


def test_variance_line_is_the_least_squares_line():
    """The luma difference's photon-transfer line from NumPy's sums is the least-squares line."""
    rng = np.random.default_rng(8)
    level = rng.uniform(0, 200, 5000)
    square = 2.0 + 0.03 * level + rng.normal(0, 1, level.size) ** 2
    slope, offset = np.polyfit(level, square, 1)
    assert _variance_line(square, level) == pytest.approx((offset, slope), rel=1e-12)
    assert _variance_line(5.0 - 0.01 * level, level) == pytest.approx((np.mean(5.0 - 0.01 * level), 0.0), rel=1e-12)
