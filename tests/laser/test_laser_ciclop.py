"""Real frames of a red line laser (a Ciclop scanner's webcam, tests/data/ciclop-laser-stripes,
CC BY-SA 4.0): the stripe on a white bust, and two stripes on the chessboard."""

import numpy as np
import pytest

import scanrig
from scanrig.io.session import read_image
from scanrig.laser.clip_level import channel_clip_levels
from tests.data_paths import real_data
from tests.laser import ciclop_board

CICLOP = real_data("ciclop-laser-stripes")
#: The laser is on the bust between these rows (above: its top; below: the turntable).
BUST_ROWS = (40, 1115)
#: Rows where the laser adds this much to the red channel (laser on minus off) carry the stripe.
STRIPE_DN = 60
#: A rank-0 centre this close to the row's strongest red difference is on the stripe, px.
ON_STRIPE_PX = 6.0


@pytest.fixture(scope="module")
def bust():
    folder = CICLOP / "laser_on_object"
    return read_image(folder / "laser.png"), read_image(folder / "laser_background.png")


@pytest.mark.parametrize("use_dark, direction", [(False, "auto"), (True, "auto"), (False, "rows")])
def test_rank0_is_on_the_bust_stripe(bust, use_dark, direction):
    on, off = bust
    t = scanrig.detect_stripe(on, color="red", dark=off if use_dark else None, direction=direction)
    u, v, line, rank = (t[k].to_numpy() for k in ("u", "v", "line", "rank"))
    best = (rank == 0) & (v == line)
    found = np.full(on.shape[0], np.nan)
    found[line[best]] = u[best]
    added = on[:, :, 0].astype(int) - off[:, :, 0]
    rows = np.arange(on.shape[0])
    rows = rows[(added.max(axis=1) > STRIPE_DN) & (rows > BUST_ROWS[0]) & (rows < BUST_ROWS[1])]
    assert rows.size > 1000
    on_stripe = np.abs(found[rows] - np.argmax(added[rows], axis=1)) < ON_STRIPE_PX
    assert on_stripe.mean() >= 0.99


#: This webcam's processing clips red here (frames of the board), DN.
WEBCAM_RED_CLIP_DN = 180


def test_the_webcams_clip_levels_are_found(bust):
    """Red piles up at 180 DN in the board's frames (145,139 pixels of the pair at 180, 6,890 at 179;
    none above 180 in the laser-off frame, 158 in the laser-on frame); the bust's red clips at 255
    and nothing else clips."""
    folder = CICLOP / "laser_on_pattern"
    on, off = read_image(folder / "laser-0-255-255-8-x.png"), read_image(folder / "laser-background-0-255-255-8-x.png")
    np.testing.assert_array_equal(channel_clip_levels(on, off), [WEBCAM_RED_CLIP_DN, 255, 255])
    np.testing.assert_array_equal(channel_clip_levels(*bust), [255, 255, 255])


#: Acceptance: each laser's centres on the flat board, undistorted, lie on a line to this RMS, px.
STRAIGHT_RMS_PX = 0.3
#: On the glint's rows the left laser's centres are the whitened beam's: centred on a red photosite,
#: 2 px apart (σ 0.58 px), so within 1.5 px of the line through the other rows...
ON_LINE_PX = 1.5
#: ... on at least this share of the rows (0.93 measured; rows 570-571 and 637-638 take the glint's flank).
ON_LINE_SHARE = 0.9


@pytest.fixture(scope="module")
def board_lines():
    """Per laser on the board: the undistorted rank <= 1 centres inside the board's outline
    ``(n, 2)`` px, their σ ``(n,)`` px and their rows ``(n,)``, with the intrinsics of the data
    set's PROVENANCE.md (:mod:`tests.laser.ciclop_board`)."""
    on, off = ciclop_board.frames()
    return ciclop_board.board_lines(scanrig.detect_stripe(on, color="red", dark=off), ciclop_board.board_outline())


@pytest.mark.parametrize("saturation_level", [None, "auto"], ids=["dtype maximum", "found: red clips at 180 DN"])
def test_the_two_stripes_on_the_board_are_straight_to_their_sigma(board_lines, saturation_level):
    """The board is flat, so each laser's centres, undistorted, lie on a line. Straightness is
    measured against the centres' own σ (the stripes are dim on black squares: σ ≈ 0.3 px). With
    the clip level found, the runs clipped at 180 DN are centred on their edges, each known to a
    red photosite (spreads 1.65 and 1.72 when σ allowed for one pixel)."""
    if saturation_level is not None:
        on, off = ciclop_board.frames()
        board_lines = ciclop_board.board_lines(scanrig.detect_stripe(on, color="red", dark=off,
                                                                     saturation_level=saturation_level),
                                               ciclop_board.board_outline())
    for p, s, _ in board_lines:
        assert len(p) > 450
        keep = np.ones(len(p), bool)
        for _ in range(5):  # a weighted line, iterated with a 5-MAD gate
            w = 1.0 / s[keep]
            a = np.c_[np.ones(keep.sum()), p[keep, 1]] * w[:, None]
            coef = np.linalg.lstsq(a, p[keep, 0] * w, rcond=None)[0]
            residual = p[:, 0] - coef[0] - coef[1] * p[:, 1]
            keep = np.abs(residual) < 5 * 1.4826 * np.median(np.abs(residual[keep]))
        assert keep.mean() > 0.8
        spread = 1.4826 * np.median(np.abs(residual[keep] / s[keep]))
        assert 0.6 <= spread <= 1.4


def test_on_the_glints_rows_the_left_laser_is_on_its_line(board_lines):
    """Where the webcam turns the saturated beam white (red dips, green and blue rise 100-130 DN),
    the left laser's points are the beam's, not the glint's flanks 3-19 px off
    (:mod:`scanrig.laser.clipped_runs`)."""
    p, _, row = board_lines[0]
    glint = (row >= ciclop_board.GLINT_ROWS[0]) & (row <= ciclop_board.GLINT_ROWS[1])
    assert glint.sum() >= 60
    residual = ciclop_board.line_residuals(p, ~glint)
    assert np.mean(np.abs(residual[glint]) < ON_LINE_PX) >= ON_LINE_SHARE


@pytest.mark.xfail(strict=True, reason="RMS 0.59 and 0.41 px. The floor is centre noise: the right laser's points "
                   "within 1 px of its line scatter 0.35 px about it, their reported sigma 0.41 px RMS (residual / "
                   "sigma 1.04 RMS); the residual is correlated along the line as the frame's noise is across rows "
                   "(0.88, 0.77, 0.67 at 1-3 rows; the colour difference's noise 0.96, 0.88, 0.77), and a cubic "
                   "(0.346 px) or no undistortion (0.348 px) leaves it: 0.3 px is below what these frames carry. "
                   "Left laser: 0.45 px off the glint's rows (rows 544-551 sit 1-1.9 px off); on them (569-638) the "
                   "whitened beam's runs are all centred on one column, 0.7 px right of the line through the other "
                   "rows (sigma 0.58 px, a Bayer period), and four rows take the glint's flank 5 px off")
def test_every_point_of_the_two_stripes_on_the_board_is_on_its_line(board_lines):
    """Every rank <= 1 centre inside the board, not only those a robust gate keeps, lies on its
    laser's straight line to ``STRAIGHT_RMS_PX``: a glint must be ranked below the stripe, or absent."""
    for p, _, _ in board_lines:
        residual = ciclop_board.line_residuals(p)
        assert np.sqrt(np.mean(residual**2)) <= STRAIGHT_RMS_PX
