"""Real frames of a red line laser (a Ciclop scanner's webcam, tests/data/ciclop-laser-stripes,
CC BY-SA 4.0): the stripe on a white bust, and two stripes on the chessboard."""

import cv2
import numpy as np
import pytest

import scanrig
from scanrig.io.session import read_image
from scanrig.laser.clip_level import channel_clip_levels
from tests.data_paths import real_data

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


@pytest.mark.parametrize("use_dark", [False, True])
def test_rank0_is_on_the_bust_stripe(bust, use_dark):
    on, off = bust
    t = scanrig.detect_stripe(on, color="red", dark=off if use_dark else None)
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


#: Undistorted columns of the two lasers on the board, px.
BOARD_LINES = ((250, 400), (560, 720))
#: Acceptance: each laser's centres on the flat board, undistorted, lie on a line to this RMS, px.
STRAIGHT_RMS_PX = 0.3


@pytest.fixture(scope="module")
def board_lines():
    """Per laser on the board: the undistorted rank <= 1 centres inside the board's outline
    ``(n, 2)`` px and their σ ``(n,)`` px, with the intrinsics of the data set's PROVENANCE.md."""
    folder = CICLOP / "laser_on_pattern"
    on, off = read_image(folder / "laser-0-255-255-8-x.png"), read_image(folder / "laser-background-0-255-255-8-x.png")
    found, corners = cv2.findChessboardCorners(cv2.cvtColor(read_image(folder / "pattern.png"), cv2.COLOR_RGB2GRAY),
                                               (11, 6))
    assert found
    grid = corners.reshape(6, 11, 2)
    outline = cv2.convexHull(np.concatenate([2 * grid[0] - grid[1], 2 * grid[-1] - grid[-2],
                                             2 * grid[:, 0] - grid[:, 1], 2 * grid[:, -1] - grid[:, -2]]))
    camera = np.array([[1429.665, 0, 478.030], [0, 1430.394, 642.597], [0, 0, 1]])
    distortion = np.array([0.02719, -0.23098, -0.00087, -0.00007, 0.50889])
    t = scanrig.detect_stripe(on, color="red", dark=off)
    u, v, line, rank, sigma = (t[k].to_numpy() for k in ("u", "v", "line", "rank", "sigma_px"))
    two = (rank <= 1) & (v == line)  # two lasers: the two most prominent peaks of a row
    q = np.c_[u, v][two]
    inside = np.array([cv2.pointPolygonTest(outline, (float(a), float(b)), False) >= 0 for a, b in q])
    q, sigma = q[inside], sigma[two][inside]
    flat = cv2.undistortPoints(q[:, None], camera, distortion, P=camera)[:, 0]
    near = [(flat[:, 0] > lo) & (flat[:, 0] < hi) for lo, hi in BOARD_LINES]
    return [(flat[m], sigma[m]) for m in near]


def test_the_two_stripes_on_the_board_are_straight_to_their_sigma(board_lines):
    """The board is flat, so each laser's centres, undistorted, lie on a line. Straightness is
    measured against the centres' own σ (the stripes are dim on black squares: σ ≈ 0.3 px)."""
    for p, s in board_lines:
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


@pytest.mark.xfail(strict=True, reason="RMS 3.1 and 0.41 px (ranked by continuity; 3.0 and 0.53 by prominence). "
                   "Left laser: on the glint's rows (569-638) the stripe is a white core (green and blue 100-130 "
                   "DN, red mostly 100-180 DN) where red minus the mean of green and blue dips, and no candidate lies "
                   "within 1 px of the line: the glint's flanks (3-19 px off) are the only ones there; without "
                   "those rows 0.45 px (rows 500-560 sit 1-1.5 px off). Right laser: this camera's red saturates "
                   "at 180 DN, so its 6-px plateau is not seen as clipped and carries two peaks 2.8 px apart, "
                   "both on the one continuous trace. With saturation_level='auto' (red found clipped at 180) "
                   "4.3 and 0.42 px: green reads 0 on the plateau (the camera's processing) and red enters it "
                   "within a pixel, so the plateau is centred on the midpoint of its edges, whose centres "
                   "scatter 0.46 px (red's edges likely quantised by the Bayer mosaic); the left laser's glint stays")
def test_every_point_of_the_two_stripes_on_the_board_is_on_its_line(board_lines):
    """Every rank <= 1 centre inside the board, not only those a robust gate keeps, lies on its
    laser's straight line to ``STRAIGHT_RMS_PX``: a glint must be ranked below the stripe, or absent."""
    for p, _ in board_lines:
        a = np.c_[np.ones(len(p)), p[:, 1]]
        residual = p[:, 0] - a @ np.linalg.lstsq(a, p[:, 0], rcond=None)[0]
        assert np.sqrt(np.mean(residual**2)) <= STRAIGHT_RMS_PX
