"""Over-exposed red stripes seen by a colour camera: clipped red, crosstalk, halo, printed dots, JPEG.

Tolerances: the acceptance figures of the detector on this held-out rendering (rank 0 within
0.5 px of the true beam centre on 95 % of the rows, median error 0.15 px, normalised error spread
0.7-1.4); two seeds each.
"""

from dataclasses import replace

import numpy as np
import pytest

import scanrig

from .colour_synth import INK_ALBEDO, RESPONSE, printed_dots, stripe_frames

#: Rows this close to the frame's top and bottom are left out (the 3 × 3 box sum needs both rows).
EDGE_ROWS = 8


def _rank0_errors(seed: int, use_dark: bool, response=RESPONSE, saturation_level=None):
    """Per row: error of the rank-0 row-scanned centre (px, NaN where none), its σ and whether it was clipped."""
    on, off, centre_u = stripe_frames(np.random.default_rng(seed), response=response)
    t = scanrig.detect_stripe(on, color="red", dark=off if use_dark else None, saturation_level=saturation_level)
    u, v, line, rank, sigma, clipped = (t[k].to_numpy() for k in ("u", "v", "line", "rank", "sigma_px", "saturated"))
    best = (rank == 0) & (v == line)
    h = on.shape[0]
    err, sig, sat = np.full(h, np.nan), np.full(h, np.nan), np.zeros(h, bool)
    err[line[best]] = u[best] - centre_u[line[best]]
    sig[line[best]], sat[line[best]] = sigma[best], clipped[best]
    rows = slice(EDGE_ROWS, h - EDGE_ROWS)
    return err[rows], sig[rows], sat[rows]


def _spread(z: np.ndarray) -> float:
    """Robust standard deviation (MAD) of normalised errors."""
    return float(1.4826 * np.median(np.abs(z)))


@pytest.mark.parametrize("seed", [0, 1])
def test_rank0_is_the_beam_centre_with_a_laser_off_frame(seed):
    err, _, sat = _rank0_errors(seed, use_dark=True)
    assert np.mean(np.abs(err) < 0.5) >= 0.95
    assert np.nanmedian(np.abs(err)) <= 0.15
    assert sat.mean() > 0.8  # the held-out set is over-exposed: most rows clip in red


@pytest.mark.parametrize("seed", [0, 1])
def test_without_a_laser_off_frame_the_centre_is_as_accurate(seed):
    err, _, _ = _rank0_errors(seed, use_dark=False)
    assert np.nanmedian(np.abs(err)) <= 0.15
    assert np.mean(np.abs(err) < 0.5) >= 0.85  # the acceptance, 0.95, below


@pytest.mark.parametrize("seed", [0, 1])
def test_without_a_laser_off_frame_rank0_is_within_half_a_pixel_on_95_percent(seed):
    """A stripe running along a printed dot's edge is weighted by the ink's reflectance, no longer
    symmetric about the beam; the colour fit of a clipped stripe follows it with a reflectance step
    (:mod:`scanrig.laser.reflectance`). Measured 0.94-0.98 on seeds 0-5 (0.88-0.95 without the step)."""
    err, _, _ = _rank0_errors(seed, use_dark=False)
    assert np.mean(np.abs(err) < 0.5) >= 0.95


@pytest.mark.parametrize("seed", [0, 1])
def test_red_clipped_below_full_scale_by_white_balance_is_found_in_jpeg(seed):
    """Red times 0.85 after the sensor clipped (a webcam's white balance): red clips at 217 DN, and
    the JPEG spreads the plateau over some 15 values. With ``saturation_level="auto"`` the level is
    read from the laser's peaks (218 DN found); the centres are then as good as at full scale
    (measured on seeds 0-5: 0.92-0.97 of rows within 0.5 px without a laser-off frame, 0.98-1.00
    with it). At the dtype's maximum the flat tops are fitted as peaks: 0.07 and 0.33 of rows."""
    response = replace(RESPONSE, white_balance=(0.85, 1.0, 1.0))
    for use_dark, share in ((True, 0.95), (False, 0.9)):
        err, _, sat = _rank0_errors(seed, use_dark, response, "auto")
        assert np.mean(np.abs(err) < 0.5) >= share
        assert np.nanmedian(np.abs(err)) <= 0.15
        assert sat.mean() > 0.8
    err, _, _ = _rank0_errors(seed, True, response)
    assert np.mean(np.abs(err) < 0.5) < 0.5


def test_without_a_laser_off_frame_a_clipped_stripe_along_a_printed_edge_is_found():
    """Rows where a printed dot's edge lies within 3 px of the beam (49 on seeds 1 and 2). The joint
    colour fit of the clipped stripe follows the edge there (a grey step in all three channels) and
    converges 4-7 px away; fitted with a reflectance step, or else refitted on the laser signal with
    its clipped pixels left out, the beam is found. Measured: a candidate within 5 px on 94 % of these
    rows (8 % without either), within 0.5 px on 51 % (4 %); the rest are skewed by the edge beyond
    0.5 px."""
    near, close = [], []
    for seed in (1, 2):
        on, _, centre_u = stripe_frames(np.random.default_rng(seed))
        albedo = printed_dots(on.shape[:2], np.random.default_rng(seed))  # the same dots: the first draws
        rows = np.arange(EDGE_ROWS, on.shape[0] - EDGE_ROWS)
        window = np.rint(centre_u[rows]).astype(int)[:, None] + np.arange(-3, 4)
        ink = albedo[rows[:, None], window] == INK_ALBEDO
        edge = rows[ink.any(axis=1) & ~ink.all(axis=1)]
        t = scanrig.detect_stripe(on, color="red")
        u, v, line = (t[k].to_numpy() for k in ("u", "v", "line"))
        by_rows = v == line
        nearest = np.full(on.shape[0], np.inf)
        np.minimum.at(nearest, line[by_rows], np.abs(u[by_rows] - centre_u[line[by_rows]]))
        near.append(nearest[edge] < 5.0)
        close.append(nearest[edge] < 0.5)
    near, close = np.concatenate(near), np.concatenate(close)
    assert near.size > 40
    assert near.mean() >= 0.85
    assert close.mean() >= 0.4


@pytest.mark.slow
@pytest.mark.parametrize("use_dark, clipped, red_gain", [(False, True, 1.0), (True, True, 1.0), (False, False, 1.0),
                                                       (True, False, 1.0), (False, True, 0.85), (True, True, 0.85)])
def test_sigma_is_honest(use_dark, clipped, red_gain):
    """Normalised errors of rank-0 centres (within 0.5 px of the truth) over four seeds: clipped
    rows (the beam on paper) and unclipped ones (the beam on printed ink; with a laser-off frame
    fitted on the luma difference, whose noise is correlated along the row: before, fitted on the
    JPEG's half-resolution colour difference, σ was understated 1.8-fold). With red clipped at
    217 DN by white balance (``red_gain`` 0.85), its level found: 0.86 and 0.87 measured."""
    response = replace(RESPONSE, white_balance=(red_gain, 1.0, 1.0))
    z = []
    for seed in range(4):
        err, sig, sat = _rank0_errors(seed, use_dark, response, "auto" if red_gain < 1 else None)
        good = (sat == clipped) & (np.abs(err) < 0.5)
        z.append(err[good] / sig[good])
    z = np.concatenate(z)
    assert z.size > (1000 if clipped else 100)
    assert 0.7 <= _spread(z) <= 1.4


def test_printed_edges_are_not_stripes():
    """A grey frame of a chessboard and dots: steps in reflectance, no laser. Candidates there
    must be few, and a stripe added to it is rank 0 on every row where it lies on white paper
    (on a black square in a white neighbourhood the pre-scan's background, a median over
    80 px, hides a stripe that dim: a known limit, see docs/detection.md)."""
    rng = np.random.default_rng(7)
    h, w = 480, 640
    vv, uu = np.mgrid[0:h, 0:w]
    paper = np.where(((vv // 40 + uu // 40) % 2 == 0) & (vv > 240), 20.0, 170.0)
    for cv, cu, r in zip(rng.uniform(0, 240, 15), rng.uniform(0, w, 15), rng.uniform(6, 20, 15)):
        paper[(vv - cv) ** 2 + (uu - cu) ** 2 < r * r] = 20.0
    noisy = np.clip(np.rint(paper + rng.normal(0, 2.0, paper.shape)), 0, 255).astype(np.uint8)
    # Without the flank test the local maxima on these edges gave 3839 candidates; what stays is
    # the white gap between two nearby dots, which is a bump on both sides.
    assert len(scanrig.detect_stripe(noisy)) < 0.1 * h
    centre_u = 321.3 + 0.1 * np.arange(h)
    stripe = 200.0 * np.exp(-0.5 * ((uu - centre_u[:, None]) / 1.5) ** 2) * paper / 170.0
    lit = np.clip(np.rint(paper + stripe + rng.normal(0, 2.0, paper.shape)), 0, 255).astype(np.uint8)
    t = scanrig.detect_stripe(lit)
    best = t.filter(np.asarray((t["rank"].to_numpy() == 0) & (t["v"].to_numpy() == t["line"].to_numpy())))
    line, u = best["line"].to_numpy(), best["u"].to_numpy()
    rows = np.arange(EDGE_ROWS, h - EDGE_ROWS)
    # rows where the beam lies on white paper, clear of any printed edge (within 6 px, 4 beam
    # widths, the edge cuts the profile: no symmetric model can place its centre)
    near = np.rint(centre_u[rows]).astype(int)[:, None] + np.arange(-6, 7)
    rows = rows[np.all(paper[rows[:, None], near] > 100, axis=1)]
    assert rows.size > 200
    found = np.full(h, np.nan)
    found[line] = u
    assert np.mean(np.abs(found[rows] - centre_u[rows]) < 1.0) >= 0.99


def _spot_errors(seed: int, use_dark: bool):
    """For every true spot: distance to the nearest detection (px), its u error over its σ_u, and
    whether it was clipped."""
    from .colour_synth import spot_frames

    on, off, centres = spot_frames(np.random.default_rng(seed))
    t = scanrig.detect_spots(on, color="red", dark=off if use_dark else None, max_candidates=200)
    u, v, cov_uu, clipped = (t[k].to_numpy() for k in ("u", "v", "cov_uu", "saturated"))
    distance = np.hypot(u[:, None] - centres[None, :, 0], v[:, None] - centres[None, :, 1])
    nearest = np.argmin(distance, axis=0)
    return (distance[nearest, np.arange(len(centres))], (u[nearest] - centres[:, 0]) / np.sqrt(cov_uu[nearest]),
            clipped[nearest])


@pytest.mark.parametrize("use_dark", [False, True])
def test_clipped_colour_spots_are_centred(use_dark):
    """Over-exposed red spots on printed paper: the clipped ones, fitted from all channels, are
    centred to 0.15 px (median); before, from the laser signal alone, 0.43 px."""
    err, _, clipped = (np.concatenate(x) for x in zip(*(_spot_errors(seed, use_dark) for seed in (0, 1))))
    assert clipped.mean() > 0.75
    assert np.median(err[clipped]) <= 0.15
    assert np.mean(err < 0.5) >= (0.9 if use_dark else 0.7)  # measured 0.94 and 0.77 (seeds 0-3)


@pytest.mark.parametrize("use_dark", [False, True])
def test_sigma_of_clipped_colour_spots_is_honest(use_dark):
    """JPEG 4:2:0 chroma and demosaicing correlate neighbouring pixels' errors (the chroma alone
    moves each centre by 0.07-0.10 px, the same in every noise draw): with every pixel taken as
    independent, the spread of error / σ is 2.2-3.2; the σ counts the pixels of 4 × 4 blocks
    as correlated."""
    err, z, clipped = (np.concatenate(x) for x in zip(*(_spot_errors(seed, use_dark) for seed in (0, 1))))
    assert 0.7 <= _spread(z[clipped & (err < 0.5)]) <= 1.4
