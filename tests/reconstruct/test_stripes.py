"""Stripe mode: epipolar matching, light plane, single-view points, reflection rejection."""

import cv2
import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.geometry import Rig
from scanrig.geometry.uncertainty import sigma_from_covariance
from scanrig.io.rig_file import save_rig
from scanrig.laser.traces import write_traces
from scanrig.reconstruct.candidates import frame_order
from scanrig.reconstruct.chi2_gate import chi2_quantile
from scanrig.reconstruct.correspondence import GATE_PROBABILITY, SIGMA_FLOOR_PX
from scanrig.reconstruct.flags import Flag
from scanrig.reconstruct.pipeline import reconstruct_session
from scanrig.reconstruct.points import read_points
from scanrig.reconstruct.stripes import reconstruct_stripes
from scanrig.reconstruct.stripes.epipolar import crossing, frame_branches, hypotheses, near_crossings
from scanrig.reconstruct.stripes.plane_step import fit_frame_plane, three_view_pass
from scanrig.reconstruct.stripes.precision import sigma_across_stripe
from scanrig.reconstruct.stripes.solve import Observations, SolvedHypotheses, solve
from scanrig.reconstruct.stripes.views import frame_views
from tests.reconstruct.synth import height_field, ring_rig, stripe_traces

#: Noise across the stripe (px); a Gaussian fit on a good stripe reaches 0.05-0.25 px (notes §2).
SIGMA_PX = 0.2
#: With 0.2 px noise the points' sigma is ~0.1-0.2 mm; 0.1 mm RMS height error is the acceptance
#: figure of the issue and about one sigma here.
RMS_TOL_M = 1e-4
#: The accuracy asked of this rig's points (largest-axis sigma, ~0.1-0.2 mm; the default 0.1 mm
#: target would leave almost none of them).
MAX_SIGMA_M = 2e-4
OUTLIER_M = 1e-3
#: Spot mode gives one point per frame; the issue asks stripes for >= 20x more.
MIN_POINTS_PER_FRAME = 20


def _height_errors(cloud):
    p = cloud.p_world
    return p[:, 2] - height_field(p[:, 0], p[:, 1])


@pytest.fixture(scope="module")
def rig():
    return ring_rig(height_m=0.6)


def test_multi_view_stripes_are_accurate_and_dense(rig):
    rng = np.random.default_rng(61)
    table = stripe_traces(rig, [-0.08, 0.0, 0.07], rng, SIGMA_PX)
    cloud, summary = reconstruct_stripes(rig, table, frame_order(table), np.random.default_rng(0),
                                         max_sigma_m=MAX_SIGMA_M)
    dz = _height_errors(cloud)
    assert np.sqrt(np.mean(dz**2)) < RMS_TOL_M
    assert np.all(np.abs(dz) < OUTLIER_M)
    assert len(cloud) / 3 >= MIN_POINTS_PER_FRAME
    assert summary["frames_with_plane"] == 3
    assert np.all(cloud.n_views[(cloud.flags & Flag.PLANE_SINGLE_VIEW) == 0] >= 2)
    # the noise predicted by sigma: height errors are one component, below the largest axis
    assert np.sqrt(np.mean((dz / cloud.sigma) ** 2)) < 1.0


def test_reflections_are_rejected_by_the_plane(rig):
    rng = np.random.default_rng(62)
    table = stripe_traces(rig, [-0.05, 0.04], rng, SIGMA_PX, reflection_camera=1)
    cloud, summary = reconstruct_stripes(rig, table, frame_order(table), np.random.default_rng(0),
                                         max_sigma_m=MAX_SIGMA_M)
    dz = _height_errors(cloud)
    assert summary["pairs_off_plane"] > 0
    assert np.mean(np.abs(dz) > OUTLIER_M) == 0.0
    assert np.sqrt(np.mean(dz**2)) < RMS_TOL_M


def test_single_view_points_come_from_the_plane(rig):
    rng = np.random.default_rng(63)
    table = stripe_traces(rig, [0.05], rng, SIGMA_PX, hidden_y_m=0.08)
    cloud, summary = reconstruct_stripes(rig, table, frame_order(table), np.random.default_rng(0),
                                         max_sigma_m=MAX_SIGMA_M)
    single = (cloud.flags & Flag.PLANE_SINGLE_VIEW) > 0
    assert summary["points_single_view"] == single.sum() > 20
    y = cloud.p_world[single, 1]
    # only camera 0 sees y > 0.08; elsewhere only the last samples of a stripe end can be single
    assert np.all((y > 0.07) | (np.abs(y) > 0.145))
    assert np.all(cloud.n_views[single] == 1)
    dz = _height_errors(cloud)
    assert np.sqrt(np.mean(dz[single] ** 2)) < RMS_TOL_M
    without, _ = reconstruct_stripes(rig, table, frame_order(table), np.random.default_rng(0), single_view=False,
                                     max_sigma_m=MAX_SIGMA_M)
    assert len(without) == len(cloud) - single.sum()


def test_stripe_session_through_the_pipeline(rig, tmp_path):
    rng = np.random.default_rng(64)
    save_rig(rig, tmp_path / "rig.toml")
    write_traces(tmp_path / "traces.parquet", stripe_traces(rig, [0.0, 0.05], rng, SIGMA_PX), {})
    summary = reconstruct_session(tmp_path, seed=7, max_sigma_m=MAX_SIGMA_M)
    cloud, comments = read_points(tmp_path / "points.ply")
    assert summary["mode"] == "stripe" and len(cloud) == summary["points"] > 100
    assert "seed: 7" in comments and set(np.unique(cloud.frame)) == {0, 1}


def test_frames_solved_by_two_workers_give_the_same_points_in_the_same_order(rig, tmp_path):
    """Each frame's plane fit draws from its own generator, seeded from the caller's in frame
    order, so the points do not depend on how many processes solved the frames."""
    rng = np.random.default_rng(66)
    save_rig(rig, tmp_path / "rig.toml")
    write_traces(tmp_path / "traces.parquet", stripe_traces(rig, [-0.06, 0.0, 0.05], rng, SIGMA_PX,
                                                            reflection_camera=1), {})
    summaries, clouds = [], []
    for workers in (1, 2):
        summaries.append(reconstruct_session(tmp_path, out_path=tmp_path / f"points_{workers}.ply", seed=3,
                                             workers=workers))
        clouds.append(read_points(tmp_path / f"points_{workers}.ply")[0])
    assert summaries[0] == {**summaries[1], "out": summaries[0]["out"]}
    assert len(clouds[0]) > 100
    for name in ("p_world", "sigma", "n_views", "residual_px", "frame", "flags"):
        np.testing.assert_array_equal(getattr(clouds[0], name), getattr(clouds[1], name))
    with pytest.raises(InputError, match=r"workers must be an integer of at least 1, got 0"):
        reconstruct_session(tmp_path, out_path=tmp_path / "points_0.ply", workers=0)
    assert not (tmp_path / "points_0.ply").exists()


def test_stripes_need_two_cameras_of_the_rig(rig):
    rng = np.random.default_rng(65)
    table = stripe_traces(rig, [0.0], rng, SIGMA_PX)
    with pytest.raises(InputError, match="multi-view reconstruction needs at least 2 cameras, the rig has 1"):
        reconstruct_stripes(Rig(rig.cameras[:1]), table, ["s000"], np.random.default_rng(0))
    with pytest.raises(InputError, match=r"traces name cameras \['cam2'\] that are not in the rig"):
        reconstruct_stripes(Rig(rig.cameras[:2]), table, ["s000"], np.random.default_rng(0))


def test_default_precision_cut_is_the_accuracy_target(rig):
    """Without max_sigma_m, points whose error across their stripe may exceed 0.1 mm are left out."""
    rng = np.random.default_rng(66)
    table = stripe_traces(rig, [-0.02, 0.06], rng, SIGMA_PX / 2)
    every, _ = reconstruct_stripes(rig, table, frame_order(table), np.random.default_rng(0), max_sigma_m=np.inf)
    cloud, summary = reconstruct_stripes(rig, table, frame_order(table), np.random.default_rng(0))
    assert summary["max_sigma_mm"] == 0.1
    assert 0 < len(cloud) < len(every)
    assert summary["points_imprecise"] == len(every) - len(cloud)
    # the bound across the stripe is at most the largest axis: every point within 0.1 mm is kept
    kept = {tuple(x) for x in cloud.p_world}
    assert kept <= {tuple(x) for x in every.p_world}
    assert all(tuple(x) in kept for x in every.p_world[every.sigma <= 1e-4])
    assert np.sqrt(np.mean(_height_errors(cloud) ** 2)) <= 1e-4


def test_sigma_across_stripe_bounds_the_error_off_the_tangent():
    """Along the stripe a point may be loose; across it (any normal) the bound is its sigma there."""
    rng = np.random.default_rng(67)
    x = np.linspace(-0.01, 0.01, 201)
    p = np.c_[x, np.zeros_like(x), np.zeros_like(x)] + rng.normal(0.0, 2e-6, (len(x), 3))
    along = np.diag([1e-3, 5e-5, 5e-5]) ** 2  # 1 mm along the stripe (x), 0.05 mm across
    across = np.diag([5e-5, 5e-5, 1e-3]) ** 2  # 1 mm across (z, a possible normal)
    cov = np.where(np.arange(len(x))[:, None, None] % 2 == 0, along, across)
    bound = sigma_across_stripe(p, cov, p)
    assert np.all(bound[1::2] == pytest.approx(1e-3))
    assert np.all((bound[::2] > 5e-5) & (bound[::2] < 6e-5))  # plus the tangent's small angular error
    assert np.all(bound <= sigma_from_covariance(cov))
    # too few neighbours for a tangent: the largest axis
    assert sigma_across_stripe(p[:3], cov[:3], p[:3]) == pytest.approx(sigma_from_covariance(cov[:3]))


def test_a_segment_crosses_a_line_where_its_ends_lie_on_both_sides_or_one_on_it():
    """The epipolar crossing test on signs agrees with ``s1 · s2 <= 0, s1 != s2`` on distances
    that are positive, negative, zero or NaN (a segment with a NaN end never crosses)."""
    rng = np.random.default_rng(3)
    for _ in range(300):
        s1, s2 = rng.choice([-2.0, -1.0, 0.0, 0.5, 1.0, np.nan], size=(2, rng.integers(1, 10), rng.integers(1, 6)))
        with np.errstate(invalid="ignore"):
            expected = (s1 * s2 <= 0.0) & (s1 != s2)
        np.testing.assert_array_equal(crossing(s1, s2), expected)


def _random_essential(rng):
    """``E = [t]x R`` of a random relative pose (unit baseline)."""
    R = cv2.Rodrigues(rng.normal(0.0, 0.6, 3))[0]
    t = rng.normal(0.0, 1.0, 3)
    t /= np.linalg.norm(t)
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return tx @ R


def test_the_pencil_of_epipolar_lines_finds_every_crossing_the_dense_test_finds():
    """Candidates from the lines' angles about the epipole, then the sign test on them, give the
    same (segment, line) pairs as the sign test on every pair: random relative poses (epipoles in
    and out of the points' spread), stripes as chains of neighbouring points, points a hair from
    the epipole in both cameras, a point on a line to rounding, and NaN points."""
    rng = np.random.default_rng(11)
    for trial in range(60):
        E = _random_essential(rng)
        n_i, n_j = rng.integers(5, 80, size=2)
        xh_i = np.c_[rng.uniform(-0.6, 0.6, (n_i, 2)), np.ones(n_i)]
        # a stripe: a random walk with steps of 1-30 % of the field
        walk = np.cumsum(rng.normal(0.0, rng.uniform(0.01, 0.3), (n_j, 2)), axis=0) + rng.uniform(-0.5, 0.5, 2)
        xh_j = np.c_[walk, np.ones(n_j)]
        e_i, e_j = np.linalg.svd(E)[2][2], np.linalg.svd(E.T)[2][2]  # E e_i = 0, Eᵀ e_j = 0
        at_epipoles = trial % 3 == 0 and abs(e_i[2]) > 1e-3 and abs(e_j[2]) > 1e-3
        if at_epipoles:  # a hair from them, where angles are not known to the margin: paired with all
            xh_i[0] = e_i / e_i[2] + np.r_[1e-9, -2e-9, 0.0]
            xh_j[1] = e_j / e_j[2] + np.r_[3e-10, 1e-10, 0.0]
        lines = xh_i @ E.T
        if trial % 4 == 1:  # a point of j on a line, and NaN points in both cameras
            xh_j[2, 0] = -(lines[0, 2] + lines[0, 1] * xh_j[2, 1]) / lines[0, 0]
            xh_j[3] = np.nan
            xh_i[4] = np.nan
            lines = xh_i @ E.T
        segments = np.r_[np.c_[np.arange(n_j - 1), np.arange(1, n_j)], rng.integers(0, n_j, (5, 2))]
        S = xh_j @ lines.T
        dense = np.argwhere(crossing(S[segments[:, 0]], S[segments[:, 1]]))
        seg, line = near_crossings(E, xh_i, xh_j, segments)
        kept = crossing(S[segments[seg, 0], line], S[segments[seg, 1], line])
        np.testing.assert_array_equal(np.c_[seg[kept], line[kept]], dense)
        if not at_epipoles:  # the candidates are the crossings, but for the margin's few
            assert seg.size <= len(dense) + 3


def test_the_plane_gate_solves_again_only_hypotheses_that_can_pass_it():
    """``gate_on_plane`` solves with the plane only the hypotheses within their χ² gate without it,
    because the plane's term only adds to χ²: on a 4-camera ring with a reflection, every other
    solved hypothesis is over its gate with the plane too; and a subset of the observations solves
    to the same rows, to the last bit, as the whole."""
    rig4 = ring_rig(azimuths_deg=(-60.0, -20.0, 20.0, 60.0), height_m=0.6)
    views = frame_views(rig4, stripe_traces(rig4, [0.02], np.random.default_rng(63), SIGMA_PX, reflection_camera=1),
                        np.eye(2) * SIGMA_FLOOR_PX**2)
    branches = frame_branches(rig4, views)
    hyps = []
    for ref in range(len(rig4)):
        mine = {j: branches[ref, j] for j in range(len(rig4)) if j != ref and branches[ref, j][0].size}
        choice = hypotheses(len(rig4), ref, len(views[ref].q), mine)
        obs = Observations(views, ref, choice)
        hyps.append(SolvedHypotheses(ref, choice, obs, *solve(rig4.cameras, obs)))
    plane = fit_frame_plane(hyps, [three_view_pass(h, GATE_PROBABILITY) for h in hyps], np.random.default_rng(0))
    assert plane is not None
    over = 0
    for h in hyps:
        every = solve(rig4.cameras, h.obs, plane, start=h.p)
        gate = chi2_quantile(GATE_PROBABILITY, h.n_other)
        skipped = h.ok & every[4] & (h.chi2 > gate)
        over += int(skipped.sum())
        assert np.all(every[2][skipped] > gate[skipped])
        rows = np.flatnonzero(h.ok)[::3]
        for whole, part in zip(every, solve(rig4.cameras, h.obs.take(rows), plane, start=h.p[rows])):
            np.testing.assert_array_equal(whole[rows], part)
    assert over > 100  # the reflection's hypotheses that the gate no longer solves again
