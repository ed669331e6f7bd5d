"""Stripes at 45° to rows and columns: both directions cross them steeply, and both keep them."""

import numpy as np
import pytest

import scanrig
from tests.laser.synth import quantize, stripe_image

AMPLITUDE, BACKGROUND, NOISE = 180.0, 10.0, 2.0
#: Lines this close to the frame's edge may lose their crossing to the edge, not to the direction.
EDGE = 5


def rank0_crossings(table, rows: bool, truth_error) -> np.ndarray:
    """The lines of one scan direction whose rank-0 centre lies within 0.5 px of the stripe, given
    ``truth_error(u, v)``: the distance of each centre from the stripe, px."""
    u, v, line, rank = (table[k].to_numpy() for k in ("u", "v", "line", "rank"))
    along = (v == line) if rows else (u == line)
    on_stripe = np.abs(truth_error(u, v)) < 0.5
    return np.unique(line[along & (rank == 0) & on_stripe])


@pytest.mark.parametrize("offset_px", [0.0, 0.5])
def test_a_45_degree_stripe_is_kept_on_every_row_and_every_column(offset_px):
    """At one pixel per line both directions cross the stripe equally steeply. The block directions
    flip along it with the noise in their evidence; each direction still keeps its crossings in the
    other's blocks. With the stripe's centre on a half pixel the rounded seeds step by 0 or 2 px
    from line to line: before, 75 of these 230 rows and 97 of the 229 columns lost their crossing."""
    rng = np.random.default_rng(17)
    shape = (240, 320)
    start = 40.0 + offset_px  # u of the stripe on row 0
    img = stripe_image(shape, lambda lines: start + lines, rng, AMPLITUDE, 1.5, BACKGROUND, NOISE)
    table = scanrig.detect_stripe(img)

    def error(u, v):
        return (u - v - start) / np.sqrt(2.0)  # distance across the stripe

    rows = np.arange(EDGE, shape[0] - EDGE)
    columns = np.arange(int(np.ceil(start)) + EDGE, int(start) + shape[0] - EDGE)  # those crossing it
    assert np.setdiff1d(rows, rank0_crossings(table, True, error)).size == 0
    assert np.setdiff1d(columns, rank0_crossings(table, False, error)).size == 0


def test_an_arc_keeps_every_steep_crossing():
    """A circle arc turns through 0-90° in the frame: every row that crosses it within 47° of its
    normal, and every such column, has its rank-0 centre on it (before: 4 rows and 4 columns near
    45° had none)."""
    rng = np.random.default_rng(3)
    shape = (400, 400)
    centre, radius = -20.0 + rng.uniform(0.0, 1.0, 2), 380.0
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    ring = AMPLITUDE * np.exp(-0.5 * ((np.hypot(u - centre[0], v - centre[1]) - radius) / 1.2) ** 2)
    table = scanrig.detect_stripe(quantize(BACKGROUND + ring + rng.normal(0.0, NOISE, shape)))

    def error(u, v):
        return np.hypot(u - centre[0], v - centre[1]) - radius

    steep = np.cos(np.deg2rad(47.0))
    for rows in (True, False):
        along = 0 if rows else 1  # the coordinate along the scan lines: u for rows, v for columns
        lines = np.arange(EDGE, shape[along] - EDGE)
        # where each line crosses the arc, and the arc's normal along the line there
        crossing = centre[along] + np.sqrt(np.maximum(radius**2 - (lines - centre[1 - along]) ** 2, 0.0))
        normal_along = (crossing - centre[along]) / radius
        inside = (crossing > EDGE) & (crossing < shape[1 - along] - EDGE)
        wanted = lines[inside & (normal_along >= steep)]
        assert wanted.size > 200
        assert np.setdiff1d(wanted, rank0_crossings(table, rows, error)).size == 0
    assert np.abs(error(table["u"].to_numpy(), table["v"].to_numpy())).max() < 0.1
