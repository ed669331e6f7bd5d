"""Ranking of stripe candidates by continuity (scanrig.laser.continuity), on synthetic candidates.

Tolerances: the stripes' centres scatter by ``CENTRE_NOISE_PX`` (σ) about a line moving
``SLOPE_PX`` per scan line, so two neighbours differ by at most SLOPE + 6·√2·σ ≈ 1.15 px, inside
the reach of one line (``MAX_STEP_PX + JITTER_PX`` = 2 px).
"""

import numpy as np
import pytest

from scanrig.errors import ShapeError
from scanrig.laser.continuity import CHAIN_CAP_LINES, chain_lengths, rank_by_continuity

#: Centre scatter of a stripe about its line, px (σ).
CENTRE_NOISE_PX = 0.1
#: Move of a stripe along the scan lines per line, px.
SLOPE_PX = 0.3
LINES = 200


def _stripe(rng, start_px, lines=None, prominence=10.0):
    """Candidates of one straight stripe on ``lines`` (default all ``LINES``): line, centre (px),
    prominence."""
    lines = np.arange(LINES) if lines is None else lines
    centre = start_px + SLOPE_PX * lines + rng.normal(0.0, CENTRE_NOISE_PX, lines.size)
    return lines, centre, np.full(lines.size, prominence)


def _join(*parts):
    return tuple(np.concatenate(column) for column in zip(*parts))


def test_a_long_trace_outranks_stronger_isolated_blobs():
    rng = np.random.default_rng(0)
    stripe = _stripe(rng, 100.0)
    blob_lines = np.arange(5, LINES, 10)
    # blobs 10 to 50 px beside the stripe and ten times as prominent: one on every tenth line, and
    # one over three lines
    blobs = _join((blob_lines, 100.0 + SLOPE_PX * blob_lines + rng.uniform(10, 50, blob_lines.size),
                   np.full(blob_lines.size, 100.0)),
                  (np.arange(40, 43), np.full(3, 400.0), np.full(3, 100.0)))
    line, centre, prominence = _join(stripe, blobs)
    rank = rank_by_continuity(line, centre, prominence)
    assert np.all(rank[:LINES] == 0)
    lengths = chain_lengths(line, centre)
    assert np.all(lengths[:LINES] == LINES)
    assert np.array_equal(lengths[LINES:], np.r_[np.ones(blob_lines.size), 3, 3, 3])


def test_two_parallel_traces_both_stay_the_more_prominent_first():
    rng = np.random.default_rng(1)
    line, centre, prominence = _join(_stripe(rng, 100.0, prominence=20.0), _stripe(rng, 104.0, prominence=10.0))
    rank = rank_by_continuity(line, centre, prominence)
    assert np.all(rank[:LINES] == 0) and np.all(rank[LINES:] == 1)
    assert np.all(chain_lengths(line, centre) == LINES)


def test_a_gap_of_one_or_two_lines_is_bridged_a_longer_one_cuts():
    rng = np.random.default_rng(2)
    for gap in (1, 2):
        lines = np.r_[0:100, 100 + gap : LINES]
        line, centre, _ = _stripe(rng, 100.0, lines)
        assert np.all(chain_lengths(line, centre) == LINES)
    line, centre, _ = _stripe(rng, 100.0, np.r_[0:100, 103:LINES])
    assert np.array_equal(chain_lengths(line, centre), np.r_[np.full(100, 100), np.full(97, 97)])


def test_a_candidate_beside_the_stripe_does_not_join_its_chain():
    """A texture candidate 1.5 px beside the stripe links to the stripe's next point, but the
    stripe's own point before it is nearer and keeps that link: the texture stays alone."""
    rng = np.random.default_rng(3)
    stripe = _stripe(rng, 100.0)
    beside = (np.array([50]), np.array([100.0 + SLOPE_PX * 51 + 1.5]), np.array([50.0]))
    line, centre, prominence = _join(stripe, beside)
    lengths = chain_lengths(line, centre)
    assert lengths[-1] == 1 and np.all(lengths[:LINES] == LINES)
    assert rank_by_continuity(line, centre, prominence)[-1] == 1


def test_long_chains_rank_alike_then_by_prominence():
    """Beyond ``CHAIN_CAP_LINES`` a longer chain is no better: a printed line or a second laser of
    more lines than the stripe does not outrank it."""
    rng = np.random.default_rng(5)
    short = _stripe(rng, 100.0, np.arange(CHAIN_CAP_LINES), prominence=30.0)
    long_ = _stripe(rng, 200.0, prominence=10.0)
    line, centre, prominence = _join(short, long_)
    rank = rank_by_continuity(line, centre, prominence)
    assert np.all(rank[:CHAIN_CAP_LINES] == 0)


def test_order_of_the_input_does_not_matter():
    rng = np.random.default_rng(6)
    line, centre, prominence = _join(_stripe(rng, 100.0), (rng.integers(0, LINES, 300), rng.uniform(0, 600, 300),
                                                          rng.uniform(5, 50, 300)))
    shuffle = rng.permutation(line.size)
    rank = rank_by_continuity(line, centre, prominence)
    assert np.array_equal(rank_by_continuity(line[shuffle], centre[shuffle], prominence[shuffle]), rank[shuffle])


def test_one_candidate_per_line_and_none():
    assert np.array_equal(rank_by_continuity(np.arange(3), np.zeros(3), np.ones(3)), np.zeros(3, np.int32))
    assert rank_by_continuity(np.zeros(0, int), np.zeros(0), np.zeros(0)).shape == (0,)
    assert chain_lengths(np.zeros(0, int), np.zeros(0)).shape == (0,)


def test_mismatched_shapes_are_refused():
    with pytest.raises(ShapeError, match=r"line and centre must be 1-D arrays of one length, got shapes \(3,\) "
                                         r"and \(2,\)"):
        chain_lengths(np.arange(3), np.zeros(2))

