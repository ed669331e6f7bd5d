"""The frame-rate code paths agree with plain reference computations.

Detection is vectorised in ways that are easy to get subtly wrong (candidate-minor stacks, an
unrolled Cholesky for many candidates and LAPACK for few, strided patch gathers, a cropped
direction map): each is checked here against the obvious, slow formulation.
"""

import cv2
import numpy as np
import pytest

import scanrig
from scanrig.laser import peaks
from scanrig.laser.fit import (
    fit_batch,
    minor_model_1d,
    minor_model_2d,
    model_1d,
    model_2d,
)
from scanrig.laser.image import prepare_image
from scanrig.laser.stacked_linalg import cholesky_solve, gram, spd_inverse

from .synth import spot_image, stripe_image


def _spd_stack(rng, n, size):
    a = rng.normal(size=(n, size, 2 * size))
    return a @ a.transpose(0, 2, 1) + 0.1 * np.eye(size)


@pytest.mark.parametrize("size", [4, 6])
def test_unrolled_cholesky_matches_lapack(size):
    rng = np.random.default_rng(11)
    h = _spd_stack(rng, 40, size)
    b = rng.normal(size=(40, size))
    x = cholesky_solve(h.transpose(1, 2, 0), b.T)
    np.testing.assert_allclose(x.T, np.linalg.solve(h, b[:, :, None])[:, :, 0], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("n", [3, 40])  # LAPACK below the unrolled threshold, unrolled above
def test_inverse_of_information_matches_lapack_and_flags_singular(n):
    rng = np.random.default_rng(12)
    jac = rng.normal(size=(4, 19, n))
    jac[2, :, 1] = 2.0 * jac[1, :, 1]  # candidate 1: two parameters not separable
    inv = spd_inverse(gram(jac))
    h = np.einsum("imn,jmn->nij", jac, jac)
    good = np.arange(n) != 1
    np.testing.assert_allclose(inv[good], np.linalg.inv(h[good]), rtol=1e-9)
    assert np.isnan(inv[1]).all()


@pytest.mark.parametrize("minor_model, public_model, n_par", [
    (lambda x: minor_model_1d(x), lambda x, p: model_1d(x, p), 4),
    (lambda x: minor_model_2d(x, x), lambda x, p: model_2d(x, x, p), 6),
], ids=["1d", "2d"])
def test_minor_and_generic_fits_agree(minor_model, public_model, n_par):
    """The same fit through the candidate-minor models and through the public (n, M) interface,
    for few candidates (LAPACK) and many (unrolled), with some pixels masked."""
    rng = np.random.default_rng(13)
    x = np.arange(-6.0, 7.0)
    for n in (3, 50):
        truth = np.empty((n, n_par))
        truth[:, 0] = rng.uniform(60, 200, n)  # peak
        truth[:, 1 : n_par // 2] = rng.uniform(-0.5, 0.5, (n, n_par // 2 - 1))  # centre(s)
        truth[:, n_par // 2 : -1] = rng.uniform(0.8, 2.0, (n, n_par // 2 - 1))  # width(s)
        truth[:, -1] = 10.0  # background
        mu, _ = public_model(x, truth)
        y = mu + rng.normal(0, 2.0, mu.shape)
        mask = rng.uniform(size=y.shape) > 0.05
        p0 = truth * 1.1
        lower = np.full(n_par, -np.inf)
        upper = np.full(n_par, np.inf)
        lower[0] = 1e-6
        generic = fit_batch(lambda p: public_model(x, p), y, mask, p0, lower, upper)
        minor = fit_batch(minor_model(x), np.ascontiguousarray(y.T), np.ascontiguousarray(mask.T), p0, lower, upper,
                          minor=True)
        np.testing.assert_allclose(minor.params, generic.params, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(minor.info_inv, generic.info_inv, rtol=1e-7)
        np.testing.assert_array_equal(minor.dof, generic.dof)


def _reference_block_max(sig):
    return cv2.dilate(sig, np.ones((4, 4), np.uint8), anchor=(0, 0))[::4, ::4]


@pytest.mark.parametrize("shape", [(3, 3), (5, 7), (16, 16), (37, 41), (1024, 1280)])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
def test_block_maxima_and_patches_match_the_plain_computation(shape, dtype):
    rng = np.random.default_rng(14)
    frame = (rng.random((shape[0] + 3, shape[1] + 5)) * 250).astype(dtype)
    sig = frame[1 : 1 + shape[0], 2 : 2 + shape[1]]  # a region of interest: not contiguous
    np.testing.assert_array_equal(peaks._block_max(sig), _reference_block_max(sig))
    hb, wb = -(-shape[0] // 4), -(-shape[1] // 4)
    take = rng.choice(hb * wb, size=min(hb * wb, 300), replace=False)
    bi, bj = np.divmod(take, wb)
    patch, bi2, bj2 = peaks._patches(sig, bi, bj)
    assert sorted(zip(bi2, bj2)) == sorted(zip(bi, bj))
    for k in range(bi2.size):
        rows = np.clip(4 * bi2[k] - 2 + np.arange(8), 0, shape[0] - 1)
        cols = np.clip(4 * bj2[k] - 2 + np.arange(8), 0, shape[1] - 1)
        np.testing.assert_array_equal(patch[:, :, k], sig[np.ix_(rows, cols)].astype(np.float32))


def test_a_curved_stripe_is_crossed_steeply_everywhere():
    """On a ring the scan direction follows the stripe: rows where it is steep, columns where it
    is flat, so every line crosses it at 30° or more from lengthwise."""
    rng = np.random.default_rng(15)
    yy, xx = np.mgrid[0:600, 0:800]
    r = np.hypot(xx - 380, yy - 290)
    img = np.clip(np.rint(10 + 180 * np.exp(-0.5 * ((r - 200) / 1.5) ** 2) + rng.normal(0, 2, r.shape)), 0, 255)
    t = scanrig.detect_stripe(img.astype(np.uint8))
    u, v, line = (t[k].to_numpy() for k in ("u", "v", "line"))
    radius = np.hypot(u - 380, v - 290)
    on_ring = np.abs(radius - 200) < 1.0
    normal = np.stack([u - 380, v - 290], axis=1) / radius[:, None]
    along_line = np.where(v == line, np.abs(normal[:, 0]), np.abs(normal[:, 1]))  # scan line · normal
    # a ring of radius 200 px crossed where steep by rows and where flat by columns: 4 √2 · 200
    # lines cross it at 45° or more, 1131 points
    assert on_ring.sum() >= 1100 and on_ring.mean() > 0.99
    assert np.all(along_line[on_ring] >= np.sin(np.deg2rad(30)))


def test_direction_map_without_candidates_scans_rows():
    empty = np.zeros((10, 12), np.float32)
    assert peaks.direction_map(empty, empty).all()


@pytest.mark.parametrize("along", ["2d", "rows", "columns"])
@pytest.mark.parametrize("search", ["patches", "frame"])
@pytest.mark.parametrize("with_dark", [False, True])
def test_candidates_match_a_plain_search(along, search, with_dark, monkeypatch):
    """Every local maximum of the 3 × 3 box sum in the flagged blocks and their neighbours that
    passes the detection test, found by a full-frame search; the same from the patches around the
    flagged blocks and from the whole-frame filters, with the noise of the cells or (laser-off frame
    subtracted) of the per-pixel model."""
    monkeypatch.setattr(peaks, "_WHOLE_FRAME_SHARE", 2.0 if search == "patches" else 0.0)
    rng = np.random.default_rng(16)
    shape = (123, 157)
    img = stripe_image(shape, lambda lines: 40.3 + 0.4 * lines, rng, 120.0, 1.5, 10.0, 2.0)
    img = np.maximum(img, spot_image(shape, [(3.2, 60.7, 150.0, 1.2, 1.2), (150.1, 2.4, 90, 1.0, 1.0)], rng))
    li = prepare_image(img, dark=spot_image(shape, [], rng, 10.0, 2.0) if with_dark else None)
    assert (li.noise_model is not None) == with_dark
    excess = peaks.prescan(li)
    found = peaks.find_candidates(li, along, excess)

    # pixels beyond the frame repeat its edge (also for the box sums just outside it)
    sig = np.pad(li.signal.astype(np.float64), 2, mode="edge")
    padded = cv2.boxFilter(sig, -1, (3, 3), normalize=False)[1:-1, 1:-1]  # box sums, frame ± 1 px
    h, w = shape
    centre = padded[1:-1, 1:-1]

    def shifted(dv, du):
        return padded[1 + dv : 1 + dv + h, 1 + du : 1 + du + w]

    if along == "2d":
        is_max = np.all([centre >= shifted(dv, du) for dv in (-1, 0, 1) for du in (-1, 0, 1)], axis=0)
    elif along == "rows":
        is_max = (centre >= shifted(0, -1)) & (centre > shifted(0, 1))
    else:
        is_max = (centre >= shifted(-1, 0)) & (centre > shifted(1, 0))
    flagged = cv2.dilate((excess > 0).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    in_flagged = np.repeat(np.repeat(flagged, 4, 0), 4, 1)[:h, :w]
    vv, uu = np.nonzero(is_max & in_flagged)
    score = (centre[vv, uu] - 9.0 * li.background_at(uu, vv)) / (3.0 * li.noise_at(uu, vv))
    keep = score >= 6.0
    assert found.u.size > (100 if along == "rows" else 3)
    np.testing.assert_array_equal(found.v, vv[keep])
    np.testing.assert_array_equal(found.u, uu[keep])
    np.testing.assert_allclose(found.score, score[keep], rtol=1e-6)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
@pytest.mark.parametrize("layout", ["frame", "transposed", "roi", "transposed roi"])
def test_prominence_table_and_erosion_match_the_windows_and_a_plain_loop(dtype, layout):
    rng = np.random.default_rng(21)
    signal = rng.integers(0, 255, size=(23, 61)).astype(dtype)
    if layout == "transposed":  # a column scan's view of a frame, as the detector passes it
        signal = np.ascontiguousarray(signal.T).T
    elif layout == "roi":  # a region of interest: a view into a larger frame
        frame = rng.integers(0, 255, size=(31, 70)).astype(dtype)
        frame[3:26, 5:66] = signal
        signal = frame[3:26, 5:66]
    elif layout == "transposed roi":  # ... and a column scan's view of it
        frame = rng.integers(0, 255, size=(70, 31)).astype(dtype)
        frame[5:66, 3:26] = signal.T
        signal = frame[5:66, 3:26].T
    n = 200
    line = rng.integers(0, 23, n)
    pos = np.r_[0, 60, 1, 59, rng.integers(0, 61, n - 4)]  # the frame's edges included
    # most at one reach (the unclipped candidates), the others spread
    reach = np.where(rng.random(n) < 0.7, 7, rng.integers(1, 40, n))
    box = peaks._box_sums_along(signal)  # the frame's box sums, in the signal's orientation
    windows = peaks._prominence_from_windows(signal, line, pos, reach)
    windows_of_box = peaks._prominence_from_windows(None, line, pos, reach, box)
    table = peaks._prominence_from_table(None, line, pos, reach, box)
    erosion = peaks._prominence_from_erosion(box, line, pos, reach)
    far = 41  # beyond the frame its edge pixels repeat
    padded = np.pad(signal.astype(np.float64), ((1, 1), (far, far)), mode="edge")
    sums = sum(padded[i : i + 23, j : j + 61 + 2 * far - 2] for i in range(3) for j in range(3))

    def plain(k):
        at = lambda x: sums[line[k], x + far - 1]  # noqa: E731
        left = min(at(pos[k] - d) for d in range(1, reach[k] + 1))
        right = min(at(pos[k] + d) for d in range(1, reach[k] + 1))
        return at(pos[k]) - max(left, right), at(pos[k])

    expected = np.array([plain(k) for k in range(n)]).T
    np.testing.assert_allclose(windows, expected, atol=1e-3)
    np.testing.assert_allclose(windows_of_box, expected, atol=1e-3)
    np.testing.assert_allclose(table, expected, atol=1e-3)
    np.testing.assert_allclose(erosion, expected, atol=1e-3)
