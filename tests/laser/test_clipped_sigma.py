"""The σ of clipped centres on a real webcam frame: no clipped centre is known better than its
run's edges allow.

The Ciclop webcam (tests/data/ciclop-laser-stripes, CC BY-SA 4.0) clips red at 180 DN
(``saturation_level="auto"``), holds green and blue at 0 under the clipped run and jumps from the
background to the clip within a pixel: a clipped centre rests on the run's two edges, each placed
only to its pixel step (1/sqrt(12) = 0.29 px), and the board's rank <= 1 centres scatter 0.35-0.4 px
(RMS) about each laser's straight line (``python benchmarks/bench_colour_stripes.py``)."""

import numpy as np
import pytest

import scanrig
from tests.laser import ciclop_board

#: No clipped rank <= 1 centre on the board may report a σ below this, px: a sixth of one edge's
#: pixel step (0.29 px), an eighth of the centres' scatter about their lines.
SIGMA_FLOOR_PX = 0.05


@pytest.mark.parametrize("use_dark", [False, True])
def test_no_clipped_centre_on_the_board_is_known_better_than_its_edges_allow(use_dark):
    on, off = ciclop_board.frames()
    t = scanrig.detect_stripe(on, color="red", dark=off if use_dark else None, saturation_level="auto")
    sigma, rank, clipped = (t[k].to_numpy() for k in ("sigma_px", "rank", "saturated"))
    best = (rank <= 1) & clipped
    assert best.sum() > 800
    assert sigma[best].min() >= SIGMA_FLOOR_PX
