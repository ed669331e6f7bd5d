"""The filter must never make good data worse: a box on a floor (step edges and corners)."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings as hypothesis_settings, strategies as st

from scanrig.errors import InputError, ShapeError
from scanrig.io.ply import read_points_with_sigma
from scanrig.surface import filter_points
from scanrig.surface.filter import POINT_TRUST_FACTOR, TRUST_FACTOR, _chart_noise, _trusted, _typical_noise
from scanrig.surface.sparse import SPARSE_CHART_POINTS

from .conftest import FAST

DATA = Path(__file__).parent / "data"
NOISE = 1e-4  # metres along the surface normal, like the demo's stripe points
HALF, HEIGHT, FLOOR = 0.04, 0.02, 0.1  # box half-width and height, floor half-width (metres)


def box_on_floor(rng, density=6e4):
    """Noisy samples of a floor z = 0 and a box [-HALF, HALF]^2 x [0, HEIGHT] standing on it.

    The walls get a third of the density (seen at grazing angles), so one chart is flat enough
    to hold the floor and the box top: a height field with a 20 mm step, 200 times the noise.
    Returns points (N, 3), metres.
    """
    def rect(n, lo, hi):
        return rng.uniform(lo, hi, (n, 2))

    floor = rect(int(density * (2 * FLOOR) ** 2), -FLOOR, FLOOR)
    floor = floor[np.max(np.abs(floor), axis=1) > HALF]
    top = rect(int(density * (2 * HALF) ** 2), -HALF, HALF)
    parts = [np.column_stack([floor, np.zeros(len(floor))]),
             np.column_stack([top, np.full(len(top), HEIGHT)])]
    normals = [np.tile([0.0, 0.0, 1.0], (len(parts[0]), 1)), np.tile([0.0, 0.0, 1.0], (len(parts[1]), 1))]
    n_wall = int(density / 3 * 2 * HALF * HEIGHT)
    for axis in range(2):
        for sign in (-1.0, 1.0):
            p = np.empty((n_wall, 3))
            p[:, axis] = sign * HALF
            p[:, 1 - axis] = rng.uniform(-HALF, HALF, n_wall)
            p[:, 2] = rng.uniform(0, HEIGHT, n_wall)
            nrm = np.zeros((n_wall, 3))
            nrm[:, axis] = sign
            parts.append(p)
            normals.append(nrm)
    points, normals = np.concatenate(parts), np.concatenate(normals)
    return points + rng.normal(0, NOISE, (len(points), 1)) * normals


def distance_to_box_on_floor(p):
    """Unsigned distance to the union of the floor outside the box and the box's top and walls."""
    q = np.abs(p[:, :2])
    # box walls and top: distance to the boundary of the solid [-HALF, HALF]^2 x [0, HEIGHT]
    # (its bottom face is not part of the surface but is never the nearest for these points)
    lo = np.array([HALF, HALF, HEIGHT / 2])
    d = np.column_stack([q, np.abs(p[:, 2] - HEIGHT / 2)]) - lo
    outside = np.linalg.norm(np.clip(d, 0, None), axis=1)
    inside = np.minimum(np.max(d, axis=1), 0)
    to_box = np.abs(outside + inside)
    # the floor outside the footprint
    gap = np.clip(HALF - np.max(q, axis=1), 0, None)  # how far inside the footprint in x-y
    to_floor = np.hypot(gap, p[:, 2])
    return np.minimum(to_box, to_floor)


def _filtered_box_on_floor(data_seed, weight_seed, max_chart_points):
    """Points of :func:`box_on_floor`, their RMS distance to the box on the floor before
    filtering and each point's distance after (metres), and the filter's result."""
    points = box_on_floor(np.random.default_rng(data_seed))
    before = np.sqrt(np.mean(distance_to_box_on_floor(points) ** 2))
    assert before == pytest.approx(NOISE, rel=0.1)
    result = filter_points(points, rng=np.random.default_rng(weight_seed), q=0.25, settings=FAST,
                           max_chart_points=max_chart_points)
    return points, before, distance_to_box_on_floor(result.denoised), result


# A moved point lies within r = 4 noise scales of a trusted fit (scale at most TRUST_FACTOR = 3
# times the reference noise, about NOISE here) and started within ~3 NOISE of the surface
MOVED_ERROR_BOUND = 15 * NOISE


def test_filter_does_not_worsen_a_box_on_a_floor():
    # the fit smooths the step and the corners: it must leave those points as they were,
    # never project them mm away (the demo's 0.09 mm cloud came out at 1.3-1.9 mm). Two charts,
    # the box top a sheet of its own; the RMS came out at 0.29-0.34 of its value before, the
    # largest error at 2.1-4.2 noise sigmas, on 20 data and 12 weight seeds
    _, before, error, _ = _filtered_box_on_floor(20261201, 1, 4096)
    assert np.sqrt(np.mean(error ** 2)) <= before
    assert np.max(error) <= MOVED_ERROR_BOUND


@pytest.mark.slow
def test_small_charts_do_not_worsen_a_box_on_a_floor():
    # in charts of 300 points 94 % of the cloud is in charts under SPARSE_CHART_POINTS members, a
    # sparse cloud: those move no point, and neither do the halves of the few larger ones that
    # the refinement cuts to that size (two of them, one straddling an edge and setting the
    # reference noise, moved floor points up to 7 sigma off it: RMS worse on 13 of 16 weight
    # seeds of the first draw below, on 5 of 40 (data, weight) draws). A chart of 400-430
    # members (overlaps) may still hold the floor and a corner of the box top with too few
    # points for a sheet (under 64): its network ramps there and moves the floor points within
    # r of the ramp, up to 5-7 sigma off. The RMS was worse on 3 of those 40 draws (by 1.5-6 %),
    # the last draw below one of them; at most one of three draws worse: a per-draw rate of
    # 3 / 40 gives two or more in 1.6 % of triples (the first two draws were worse before, so
    # this fails without the rule on the halves)
    worse = 0
    for data_seed, weight_seed in ((20261201, 0), (20261201, 1), (2, 1)):
        points, before, error, result = _filtered_box_on_floor(data_seed, weight_seed, 300)
        assert result.sparse.mean() >= 0.5
        big = np.zeros(len(points), bool)
        for chart in result.charts:
            big[chart.members] |= len(chart.members) >= SPARSE_CHART_POINTS
        moved = np.any(result.denoised != points, axis=1)
        assert not np.any(moved & ~big)  # only charts of at least SPARSE_CHART_POINTS members move points
        assert np.max(error) <= MOVED_ERROR_BOUND
        worse += np.sqrt(np.mean(error ** 2)) > before
    assert worse <= 1


def test_point_sigma_guards_a_sparse_cloud_of_one_chart():
    # 164 points over the whole scene (like the spot-mode demo's 52): it starts as one chart,
    # whose network cannot follow the box; the relative trust test has no other chart to
    # compare with, so the points' own predicted sigma is the reference, both for halving the
    # chart and for moving points (without it this cloud came out ~2 mm)
    points = box_on_floor(np.random.default_rng(20261201), density=4e3)
    before = distance_to_box_on_floor(points)
    result = filter_points(points, rng=np.random.default_rng(1), q=0.25, settings=FAST,
                           point_sigma=np.full(len(points), NOISE))
    error = distance_to_box_on_floor(result.denoised)
    assert np.sqrt(np.mean(error ** 2)) <= np.sqrt(np.mean(before ** 2))
    assert np.max(error) <= 15 * NOISE


def test_a_chart_moves_points_of_known_sigma_only_where_it_predicts_better_than_them():
    # one chart over a noisy plane; the points' own sigma set so that the chart's held-out
    # scale is 1.5 or 2 times it: below POINT_TRUST_FACTOR (sqrt 3) the fit replaces the points,
    # above it (but below TRUST_FACTOR, so the chart is not halved) it moves none
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.1, 0.1, (1500, 2))
    points = np.column_stack([xy, 0.1 * xy[:, 0] + rng.normal(0, NOISE, len(xy))])
    free = filter_points(points, rng=np.random.default_rng(0), q=0.25, settings=FAST)
    _, sigma_fit = _chart_noise(free.fits, free.z_scale, FAST.constants.r)
    assert len(free.charts) == 1
    assert 1.5 < POINT_TRUST_FACTOR < 2.0 < TRUST_FACTOR
    for ratio, moves in ((1.5, True), (2.0, False)):
        result = filter_points(points, rng=np.random.default_rng(0), q=0.25, settings=FAST,
                               point_sigma=np.full(len(points), sigma_fit[0] / ratio))
        moved = np.any(result.denoised != points, axis=1)
        assert len(result.charts) == 1
        assert moved.mean() > 0.9 if moves else not moved.any()


def test_point_sigma_is_checked():
    points = box_on_floor(np.random.default_rng(0), density=2e3)
    with pytest.raises(ShapeError):
        filter_points(points, rng=np.random.default_rng(0), point_sigma=np.ones(3))
    with pytest.raises(InputError):
        filter_points(points, rng=np.random.default_rng(0), point_sigma=np.zeros(len(points)))


@pytest.mark.parametrize("seed", [0, 1])
def test_with_point_sigma_no_point_moves_beyond_its_own_noise(seed):
    # the spot demo's cloud: 62 points over a scene, the floor the majority, the block top 80 mm
    # up a small cluster; one chart fits the floor within noise and flags the block, whose points
    # were projected 80 mm down onto the floor's fit (seed 1) -- and looked accurate, the floor
    # being a true surface. A point r of its own sigmas off the fit is flagged, never moved.
    points, sigma = read_points_with_sigma(DATA / "demo_spot_points.ply")
    result = filter_points(points, rng=np.random.default_rng(seed), q=0.25, settings=FAST, point_sigma=sigma)
    moved = np.linalg.norm(result.denoised - points, axis=1)
    assert np.all(moved <= result.settings.constants.r * sigma * (1 + 1e-9))


def test_a_chart_holding_a_step_is_split_into_sheets_and_both_sides_kept():
    # a floor and a plateau 20 mm (200 noise sigmas) up, no wall between them: one height field
    # whose single fit took the plateau (35 % of the points) for a cluster of outliers, more
    # than the q = 25 % it tolerates (63 % inliers); halving the chart until each piece fitted
    # kept 93-97 % (97-99 % away from the step); split into its two sheets: 99.9 % on three
    # weight seeds, all of the points away from the step
    rng = np.random.default_rng(7)
    xy = rng.uniform(-0.1, 0.1, (3000, 2))
    points = np.column_stack([xy, 0.02 * (xy[:, 0] > 0.03) + rng.normal(0, NOISE, len(xy))])
    away = np.abs(xy[:, 0] - 0.03) > 0.01
    result = filter_points(points, rng=np.random.default_rng(0), q=0.25, settings=FAST)
    assert len(result.charts) == 2 and all(chart.claim is not None for chart in result.charts)
    assert result.inlier.mean() >= 0.99
    assert result.inlier[away].mean() >= 0.999


@hypothesis_settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.floats(0.1, 10.0), st.integers(1, 50)), min_size=1, max_size=8))
def test_typical_noise_is_the_median_over_the_points(charts_and_sizes):
    sigma = np.array([s for s, _ in charts_and_sizes])
    charts = [SimpleNamespace(members=np.arange(n)) for _, n in charts_and_sizes]
    every_point = np.sort(np.repeat(sigma, [n for _, n in charts_and_sizes]))
    assert _typical_noise(charts, sigma) == every_point[(len(every_point) + 1) // 2 - 1]


def test_a_chart_too_small_for_its_networks_is_not_trusted():
    # a fit as tight as the reference does not vouch for fewer than SPARSE_CHART_POINTS members
    # (a slice of a blob of reflections); a loose fit never does
    charts = [SimpleNamespace(members=np.arange(n)) for n in (SPARSE_CHART_POINTS - 1, SPARSE_CHART_POINTS,
                                                               10 * SPARSE_CHART_POINTS)]
    sigma_ref = 2e-4
    sigma_fit = np.array([sigma_ref, sigma_ref, 1.01 * TRUST_FACTOR * sigma_ref])
    assert _trusted(charts, sigma_fit, sigma_ref).tolist() == [False, True, False]


def test_a_blob_of_reflections_cut_into_its_own_charts_is_flagged():
    # a noisy plane with a patch replaced by reflections 5-30 sigma above it (no true point
    # under them), dense enough that small charts hold nothing else: their own fits are loose
    # (a rough "surface"). Scored against their own scale, 0.31 of the blob was flagged (0.23
    # on another draw); against the reference noise, every point farther than r = 4 reference
    # sigmas from the blob chart's fit, which runs through the blob: of heights spread evenly
    # over 25 sigma, about 1 - 8 / 25 = 0.68 (measured 0.73 here, 0.65 on another draw)
    rng = np.random.default_rng(11)
    xy = rng.uniform(-0.1, 0.1, (6000, 2))
    z = rng.normal(0, NOISE, len(xy))
    blob = np.hypot(xy[:, 0] - 0.03, xy[:, 1]) < 0.03
    z[blob] += rng.uniform(5 * NOISE, 30 * NOISE, blob.sum())
    result = filter_points(np.column_stack([xy, z]), rng=np.random.default_rng(0), q=0.25, settings=FAST,
                           max_chart_points=300)
    assert np.mean(~result.inlier[blob]) >= 0.6
    assert np.mean(~result.inlier[~blob]) <= 0.01


def laser_stripes(rng, sigma, n_stripes=15, n_along=120):
    """Points of a stripe scan of the plane z = 0.1x - 0.05y: ``n_stripes`` wavy lines across
    [-0.1, 0.1]^2 (m), dense along each line and 14 mm apart, whose errors are shared along the
    stripe (an offset and a slow wave, ~sigma; what one frame's calibration and light plane give)
    plus an independent 5 % of sigma. Returns points (N, 3), metres."""
    x0 = np.linspace(-0.1, 0.1, n_stripes)[:, None]
    y = np.linspace(-0.1, 0.1, n_along)
    x = x0 + 0.002 * np.sin(10 * y + rng.uniform(0, 6, (n_stripes, 1)))
    shared = rng.normal(0, sigma, (n_stripes, 1)) + 0.5 * sigma * np.sin(30 * y + rng.uniform(0, 6, (n_stripes, 1)))
    z = 0.1 * x - 0.05 * y + shared + rng.normal(0, 0.05 * sigma, x.shape)
    return np.column_stack([x.ravel(), np.broadcast_to(y, x.shape).ravel(), z.ravel()])


@pytest.mark.parametrize("seed", [0, 1])
def test_stripes_whose_errors_are_shared_along_them_are_not_flagged(seed):
    # every point lies within ~3 of its own sigmas of the plane. Neighbours along a stripe
    # predict each other far closer than sigma; with that as the noise scale, 4-14 % of the
    # points (whole stripes) were flagged and the cloud cut into 11-21 charts. The points'
    # own sigma bounds the scale from below, and normals come from neighbourhoods that reach
    # the next stripes.
    sigma = 2e-4
    points = laser_stripes(np.random.default_rng(seed), sigma)
    result = filter_points(points, rng=np.random.default_rng(seed), q=0.25, settings=FAST,
                           point_sigma=np.full(len(points), sigma))
    assert np.mean(~result.inlier) <= 0.01
    assert len(result.charts) <= 4
