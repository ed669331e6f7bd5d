"""Spot detection: accuracy at the Cramér–Rao bound, honest sigma, all candidates, no false ones."""

import numpy as np
import pytest

import scanrig
from scanrig.errors import ShapeError
from scanrig.laser.crb import crb_spot, effective_noise
from scanrig.laser.traces import SCHEMA

from .synth import spot_image

AMPLITUDE, BACKGROUND, NOISE = 180.0, 10.0, 2.0   # the acceptance setting (8-bit)
# Acceptance figures of issue 5.
RMS_OVER_CRB_MAX = 1.2
BIAS_MAX_PX = 0.02
SIGMA_RATIO_RANGE = (0.8, 1.25)


def _grid_frame(rng, sigma, spacing=40, shape=(1024, 1280)):
    gv, gu = np.meshgrid(np.arange(30, shape[0] - 20, spacing), np.arange(30, shape[1] - 20, spacing), indexing="ij")
    u = gu.ravel() + rng.uniform(-0.5, 0.5, gu.size)
    v = gv.ravel() + rng.uniform(-0.5, 0.5, gv.size)
    img = spot_image(shape, [(a, b, AMPLITUDE, sigma, sigma) for a, b in zip(u, v)], rng, BACKGROUND, NOISE)
    return img, u, v


def _match(table, u, v):
    """Errors of each detection against the nearest true spot."""
    du = table["u"].to_numpy()[:, None] - u[None, :]
    dv = table["v"].to_numpy()[:, None] - v[None, :]
    j = np.argmin(du**2 + dv**2, axis=1)
    rows = np.arange(j.size)
    return du[rows, j], dv[rows, j], j


@pytest.mark.parametrize("sigma", [0.8, 1.5, 2.5])
def test_spot_centres_reach_the_cramer_rao_bound_without_bias(sigma):
    rng = np.random.default_rng(301 + int(10 * sigma))
    img, u, v = _grid_frame(rng, sigma)
    table = scanrig.detect_spots(img, max_candidates=10_000)
    assert len(table) == u.size
    eu, ev, j = _match(table, u, v)
    assert np.all(np.hypot(eu, ev) < 0.2)
    offsets_u = u[j] - np.rint(u[j])
    bound = crb_spot(AMPLITUDE, sigma, offsets_u, v[j] - np.rint(v[j]), effective_noise(NOISE))
    rms = np.sqrt(np.mean(eu**2))
    assert rms <= RMS_OVER_CRB_MAX * np.sqrt(np.mean(bound**2))
    bins = np.digitize(offsets_u, np.linspace(-0.5, 0.5, 6)[1:-1])
    assert max(abs(eu[bins == k].mean()) for k in range(5)) <= BIAS_MAX_PX
    z = np.concatenate([eu / np.sqrt(table["cov_uu"].to_numpy()), ev / np.sqrt(table["cov_vv"].to_numpy())])
    assert SIGMA_RATIO_RANGE[0] <= np.std(z) <= SIGMA_RATIO_RANGE[1]


def test_secondary_reflections_are_all_reported():
    """Recall of the true spot and a 30-100 % reflection 6-30 px away, over 200 frames."""
    rng = np.random.default_rng(302)
    n_frames, found, ranked_right = 200, 0, 0
    for _ in range(n_frames):
        u0, v0 = rng.uniform(40, 150, 2)
        ratio = rng.uniform(0.3, 1.0)
        angle, dist = rng.uniform(0, 2 * np.pi), rng.uniform(6, 30)
        u1, v1 = u0 + dist * np.cos(angle), v0 + dist * np.sin(angle)
        img = spot_image((192, 192), [(u0, v0, AMPLITUDE, 1.5, 1.5), (u1, v1, ratio * AMPLITUDE, 1.5, 1.5)], rng,
                         BACKGROUND, NOISE)
        t = scanrig.detect_spots(img)
        d0 = np.hypot(t["u"].to_numpy() - u0, t["v"].to_numpy() - v0)
        d1 = np.hypot(t["u"].to_numpy() - u1, t["v"].to_numpy() - v1)
        found += int(d0.min() < 0.5) + int(d1.min() < 0.5)
        ranked_right += int(t["rank"].to_numpy()[np.argmin(d0)] == 0) if ratio < 0.9 else 1
    assert found / (2 * n_frames) >= 0.99
    assert ranked_right == n_frames


def test_noise_alone_gives_almost_no_candidates():
    """At most 1 false candidate per 100 frames: 25 full frames of noise must give none (if the
    rate were 0.01/frame, P(0 in 25) = 0.78; a rate of 0.2/frame would pass with P < 0.01)."""
    rng = np.random.default_rng(303)
    false = sum(len(scanrig.detect_spots(spot_image((1024, 1280), [], rng, BACKGROUND, NOISE))) for _ in range(25))
    assert false == 0


def test_all_dark_frame_gives_an_empty_table_with_the_schema():
    t = scanrig.detect_spots(np.zeros((480, 640), np.uint8))
    assert len(t) == 0 and t.schema.equals(SCHEMA)


def test_saturated_spot_centre_is_unbiased():
    """A spot 5x over the clip level: the fit ignores the flat core; the error stays at the
    tails' noise level, and the reported sigma covers it."""
    rng = np.random.default_rng(304)
    errs, sigmas = [], []
    for _ in range(40):
        u, v = rng.uniform(60, 70, 2)
        t = scanrig.detect_spots(spot_image((128, 128), [(u, v, 5 * 245.0, 2.0, 2.0)], rng, BACKGROUND, NOISE))
        assert len(t) == 1 and t["saturated"][0].as_py()
        errs.append([t["u"][0].as_py() - u, t["v"][0].as_py() - v])
        sigmas.append([np.sqrt(t["cov_uu"][0].as_py()), np.sqrt(t["cov_vv"][0].as_py())])
    z = np.array(errs) / np.array(sigmas)
    # no bias: the mean error of 40 spots is within 4 standard errors of zero
    assert np.all(np.abs(np.mean(errs, axis=0)) < 4 * np.mean(sigmas, axis=0) / np.sqrt(len(errs)))
    assert SIGMA_RATIO_RANGE[0] <= np.std(z) <= 1.5  # 80 samples: sd of the spread estimate ~8 %


def test_sixteen_bit_roi_and_colour_give_full_frame_coordinates():
    rng = np.random.default_rng(305)
    grey = spot_image((200, 300), [(150.3, 80.6, 180.0 * 256, 1.5, 1.5)], rng, 2560.0, 512.0, dtype=np.uint16)
    t = scanrig.detect_spots(grey, roi=(100, 40, 220, 160))
    assert len(t) == 1
    assert t["u"][0].as_py() == pytest.approx(150.3, abs=0.05) and t["v"][0].as_py() == pytest.approx(80.6, abs=0.05)
    red = spot_image((200, 300), [(150.3, 80.6, AMPLITUDE, 1.5, 1.5)], rng, 60.0, NOISE)
    rgb = np.stack([red, np.full_like(red, 60), np.full_like(red, 60)], axis=-1)
    t = scanrig.detect_spots(rgb, color="red", camera="cam0", frame="f7")
    assert len(t) == 1 and t["camera"][0].as_py() == "cam0" and t["frame"][0].as_py() == "f7"
    assert t["u"][0].as_py() == pytest.approx(150.3, abs=0.05)


def test_bad_image_names_the_argument():
    with pytest.raises(ShapeError, match="image must be an 8- or 16-bit image"):
        scanrig.detect_spots(np.zeros((10, 10)))


def _exposure(rng, level_dn, gain_e_per_dn=10000.0 / 255.0, read_noise_e=12.0, black_dn=2.0):
    """One 8-bit exposure of a noise-free scene (DN above black): Poisson electrons, read noise, rounding."""
    electrons = rng.poisson(level_dn * gain_e_per_dn) + rng.normal(0.0, read_noise_e, level_dn.shape)
    return np.clip(np.rint(black_dn + electrons / gain_e_per_dn), 0, 255).astype(np.uint8)


def test_static_glints_in_the_dark_frame_are_not_candidates_but_a_faint_spot_is():
    # Room light glinting on polished metal: bright in the dark frame and in every laser frame.
    # Their difference carries the shot noise of their level (about 3.4 DN at 220 DN, against
    # 0.7 DN on the dim background), which a threshold from the local cell noise let through.
    rng = np.random.default_rng(601)
    shape = (256, 320)
    vv, uu = np.mgrid[: shape[0], : shape[1]].astype(float)
    scene = np.full(shape, 3.0)
    glints = [(u, v) for v in range(24, 240, 36) for u in range(24, 300, 44)]
    for u, v in glints:
        scene += 220.0 * np.exp(-((uu - u) ** 2 + (vv - v) ** 2) / (2 * 1.5**2))
    spot_u, spot_v = 190.3, 205.6  # between glints
    laser = 14.0 * np.exp(-((uu - spot_u) ** 2 + (vv - spot_v) ** 2) / (2 * 1.0**2))
    dark = _exposure(rng, scene)
    frame = _exposure(rng, scene + laser)
    table = scanrig.detect_spots(frame, dark=dark)
    assert len(table) == 1
    assert table["u"][0].as_py() == pytest.approx(spot_u, abs=0.3)
    assert table["v"][0].as_py() == pytest.approx(spot_v, abs=0.3)


def test_glints_at_and_beyond_the_clip_level_are_not_candidates():
    # One glint clipped in the dark frame too (it cannot show the laser), one just below the clip
    # level that noise pushes over it in some frames: neither may read as a spot at full scale.
    rng = np.random.default_rng(602)
    shape = (96, 128)
    vv, uu = np.mgrid[: shape[0], : shape[1]].astype(float)
    scene = 3.0 + sum(a * np.exp(-((uu - u) ** 2 + (vv - v) ** 2) / (2 * 2.0**2))
                      for u, v, a in ((40, 50, 600.0), (80, 70, 250.0)))
    laser = 60.0 * np.exp(-((uu - 90.4) ** 2 + (vv - 30.7) ** 2) / (2 * 1.2**2))
    dark = _exposure(rng, scene)
    assert (dark == 255).sum() > 5
    for _ in range(8):
        frame = _exposure(rng, scene + laser)
        table = scanrig.detect_spots(frame, dark=dark)
        assert len(table) == 1 and table["u"][0].as_py() == pytest.approx(90.4, abs=0.2)
