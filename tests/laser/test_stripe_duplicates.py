"""One peak fitted twice (two seeds that converged onto it) is one candidate (scanrig.laser.stripes.distinct_peaks).

Tolerances: ``SAME_PEAK_PX`` (0.5 px) is the detector's own limit; the synthetic centres sit
0.1 px inside or outside it, far beyond float rounding.
"""

import numpy as np

import scanrig
from scanrig.io.session import read_image
from scanrig.laser.stripes import SAME_PEAK_PX, distinct_peaks
from tests.data_paths import real_data


def test_the_better_determined_of_one_peak_fitted_twice_stays():
    # line 3: one peak fitted three times in a chain (gaps 0.4, 0.4: 0.8 px end to end), the
    # middle one best determined; line 5: two fits 0.4 px apart, the second better; line 5 also
    # holds a distinct peak 0.6 px beyond; line 7: a lone fit
    line = np.array([5, 3, 3, 5, 7, 3, 5])
    centre = np.array([10.0, 20.0, 20.4, 10.4, 30.0, 20.8, 10.4 + SAME_PEAK_PX + 0.1])
    var = np.array([0.02, 0.03, 0.01, 0.01, 0.05, 0.02, 0.04])
    keep = distinct_peaks(line, centre, var)
    assert keep.tolist() == [False, False, True, True, True, False, True]


def test_distinct_peaks_keep_every_fit():
    line = np.array([0, 0, 1, 2])
    centre = np.array([4.0, 4.0 + SAME_PEAK_PX + 0.1, 4.0, 4.0])
    assert distinct_peaks(line, centre, np.full(4, 0.01)).all()
    assert distinct_peaks(np.zeros(0, int), np.zeros(0), np.zeros(0)).shape == (0,)


def test_no_peak_of_the_ciclop_bust_is_fitted_twice():
    """With its laser-off frame the bust gave 105 pairs of fits within 0.5 px on one line."""
    folder = real_data("ciclop-laser-stripes") / "laser_on_object"
    on, off = read_image(folder / "laser.png"), read_image(folder / "laser_background.png")
    t = scanrig.detect_stripe(on, color="red", dark=off)
    line, u, v = (t[k].to_numpy() for k in ("line", "u", "v"))
    by_rows = v == line
    centre = np.where(by_rows, u, v)
    order = np.lexsort((centre, by_rows, line))
    line, by_rows, centre = line[order], by_rows[order], centre[order]
    same_line = (line[1:] == line[:-1]) & (by_rows[1:] == by_rows[:-1])
    assert same_line.sum() > 50  # many lines hold several candidates (79): the check is not empty
    assert not np.any(same_line & (centre[1:] - centre[:-1] <= SAME_PEAK_PX))
