"""Charts holding a step are split into sheets fitted separately."""

from pathlib import Path

import numpy as np
import pytest

from scanrig.surface import filter_points
from scanrig.surface.charts import Claim, estimate_normals, split_charts
from scanrig.surface.filter import project_on_surface
from scanrig.surface.sheets import sheet_labels, split_sheets

from .conftest import FAST, SIGMA

DATA = Path(__file__).parent / "data"

STEP = 20 * SIGMA  # step height, metres
N_SIDE = 48
SPACING = 2.0 / (N_SIDE - 1)


def step_grid(rng, n_ghosts=0):
    """Grid over [-1, 1]^2 on z = STEP where x > 0.05 (0 elsewhere), noise SIGMA, and
    ``n_ghosts`` edge ghosts within one spacing of the step at heights lam * STEP, lam ~ U(0, 1).

    Returns points (N, 3), upper side (N,) bool, ghost mask (N,).
    """
    g = np.linspace(-1, 1, N_SIDE)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    upper = x > 0.05
    z = STEP * upper + rng.normal(0, SIGMA, x.size)
    ghost = np.zeros(x.size, bool)
    edge = np.flatnonzero(np.abs(x - 0.05) <= SPACING)
    ghost[rng.choice(edge, n_ghosts, replace=False)] = True
    z[ghost] = rng.uniform(0, STEP, n_ghosts)
    return np.column_stack([x, y, z]), upper, ghost


def test_a_step_is_two_sheets_and_a_crease_or_a_saddle_one():
    rng = np.random.default_rng(5)
    points, upper, _ = step_grid(rng)
    label = sheet_labels(points[:, :2], points[:, 2], q=0.25, cut=4.0)
    sheets = np.unique(label[label >= 0])
    assert len(sheets) == 2
    assert np.mean(label >= 0) >= 0.97  # nearly every point is on a surface
    for sheet in sheets:  # each sheet lies on one side
        assert len(np.unique(upper[label == sheet])) == 1
    xy = points[:, :2]
    for z in (0.4 * np.abs(xy[:, 0] - 0.1), 0.5 * (xy[:, 0] ** 2 - xy[:, 1] ** 2)):
        label = sheet_labels(xy, z + rng.normal(0, SIGMA, len(z)), q=0.25, cut=4.0)
        assert len(np.unique(label[label >= 0])) == 1


def test_edge_ghosts_between_the_levels_do_not_bridge_them():
    # half of the points within one spacing of the step are ghosts at every height between
    # the two levels; each lies near the plane of one level at most, so it cannot link them
    points, upper, ghost = step_grid(np.random.default_rng(6), n_ghosts=N_SIDE * 2)
    label = sheet_labels(points[:, :2], points[:, 2], q=0.25, cut=4.0)
    big = [s for s in np.unique(label[label >= 0]) if np.sum(label == s) >= 64]
    assert len(big) == 2
    for sheet in big:
        assert len(np.unique(upper[(label == sheet) & ~ghost])) == 1


def test_sheets_partition_the_chart_and_claim_their_own_side():
    rng = np.random.default_rng(7)
    points, upper, ghost = step_grid(rng, n_ghosts=N_SIDE)
    normals = estimate_normals(points)
    charts = split_charts(points, normals, max_points=len(points), q=0.25)
    assert len(charts) == 1
    sheets = split_sheets(points, normals, charts, q=0.25, cut=4.0)
    assert len(sheets) == 2
    np.testing.assert_array_equal(np.sort(np.concatenate([s.core for s in sheets])), np.arange(len(points)))
    for sheet in sheets:
        side = upper[sheet.members[~ghost[sheet.members]]]
        assert len(np.unique(side)) == 1  # true points of one level only
        # the sheet holds on its own side, away from the step
        probe = points[(upper == side[0]) & (np.abs(points[:, 0] - 0.05) > 2 * SPACING)]
        assert np.all(sheet.holds(probe))
        other = points[(upper != side[0]) & (np.abs(points[:, 0] - 0.05) > 2 * SPACING)]
        assert not np.any(sheet.holds(other))


def test_a_full_column_of_edge_ghosts_does_not_bridge_the_levels_of_a_tilted_chart():
    # a mixed pixel in every row (all sites within one spacing of the step are ghosts) and 20 %
    # uniform gross errors. The chart's principal axes lean towards the step (least squares
    # through two levels), and in that frame the column of ghosts leans into a ramp between the
    # levels: cut in that frame, 4 of these 6 clouds were one sheet; in the frame of the points'
    # median normal, 1
    two_sheets = 0
    for seed in range(8, 14):
        rng = np.random.default_rng(seed)
        points, upper, ghost = step_grid(rng, n_ghosts=2 * N_SIDE)
        gross = rng.choice(np.flatnonzero(~ghost), len(points) // 5, replace=False)
        points[gross, 2] = rng.uniform(-STEP / 2, 3 * STEP / 2, len(gross))
        normals = estimate_normals(points)
        charts = split_charts(points, normals, max_points=len(points), q=0.3)
        assert len(charts) == 1 and abs(charts[0].rotation[2, 0]) > 0.1  # tilted towards the step
        sheets = split_sheets(points, normals, charts, q=0.3, cut=4.0)
        true = ~ghost & ~np.isin(np.arange(len(points)), gross)
        if len(sheets) == 2 and all(len(np.unique(upper[s.core[true[s.core]]])) == 1 for s in sheets):
            two_sheets += 1
    assert two_sheets >= 5


def test_gross_errors_below_the_breakdown_point_do_not_inflate_the_sheets_noise_scale():
    # 35 % uniform gross errors at q = 0.5 and a ghost in every edge site: the q-trimmed scale of
    # the local-plane residuals is ~1.6x the noise, so points 6 sigma off a plane were "on" it
    # and chains of them linked the levels (2 of these 6 clouds were one sheet); the scale
    # refined inside 2.5 scales keeps them apart
    for seed in range(20, 26):
        rng = np.random.default_rng(seed)
        points, upper, ghost = step_grid(rng, n_ghosts=2 * N_SIDE)
        gross = rng.choice(np.flatnonzero(~ghost), int(0.35 * len(points)), replace=False)
        points[gross, 2] = rng.uniform(-STEP / 2, 3 * STEP / 2, len(gross))
        label = sheet_labels(points[:, :2], points[:, 2], q=0.5, cut=4.0)
        assert np.sum(np.bincount(label[label >= 0]) >= 64) == 2, seed


def test_a_corner_cut_off_by_a_band_of_reflections_stays_in_the_sheet():
    # a band of one-sided reflections (5 sigma to 0.3 above) across a plane breaks every link
    # through it; the corner beyond it (253 points) continues the plane and is joined to it
    # (without the join: two sheets on each of these 5 draws)
    g = np.linspace(-1, 1, N_SIDE)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    blob = np.abs(x + y - 0.9) < 0.2
    for seed in range(5):
        rng = np.random.default_rng(seed)
        z = 0.4 * x + rng.normal(0, SIGMA, x.size)
        z[blob] += rng.uniform(5 * SIGMA, 0.3, blob.sum())
        label = sheet_labels(np.column_stack([x, y]), z, q=0.3, cut=4.0)
        sheets = np.flatnonzero(np.bincount(label[label >= 0]) >= 64)
        assert len(sheets) == 1, seed
        assert np.mean(label[(x + y > 1.15)] == sheets[0]) > 0.9  # the corner is in it


def test_a_few_stray_points_of_a_sheet_do_not_claim_a_place():
    # two sheets side by side, and two points of sheet 1 deep inside sheet 0's half: the
    # places around them stay sheet 0's (most of the nearest sheet points vote for it)
    g = np.linspace(0, 1, 20)
    xy = np.column_stack([a.ravel() for a in np.meshgrid(g, g)])
    label = (xy[:, 0] > 0.5).astype(int)
    label[[45, 46]] = 1
    claim = Claim(np.column_stack([xy, np.zeros(len(xy))]), label, 0, np.array([0.0, 0.0, 1.0]))
    probe = np.column_stack([xy[[45, 46]] + 0.01, [0.3, -0.3]])  # heights do not matter
    assert np.all(claim.holds(probe))
    np.testing.assert_array_equal(claim.owner(np.array([[0.2, 0.5, 0.0], [0.8, 0.5, 0.0]])), [0, 1])


def test_a_chain_of_edge_ghosts_does_not_join_the_levels():
    # the benchmark's step at 20 % outliers (64 x 64, noise 0.01, step 0.2, outliers drawn with
    # seed (71, 33)): three edge ghosts whose trimmed planes run up the step (slopes 1-2, the
    # levels' 0-0.2) link low level, ghost, ghost, ghost, high level. Linked so, the chart was one
    # sheet and its network drew a ramp 6.2 spacings wide; linked where the planes also agree in
    # slope, it is two
    noise, spacing = 0.01, 2.0 / 63
    g = np.linspace(-1, 1, 64)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    points = np.column_stack([x, y, np.load(DATA / "step_ghost_chain.npy")])
    edge = (x - 0.1 * y - 0.05) / np.hypot(1.0, 0.1)  # signed distance to the step's edge
    upper = edge > 0
    normals = estimate_normals(points)
    charts = split_charts(points, normals, max_points=len(points), q=0.3)
    assert len(charts) == 1
    sheets = split_sheets(points, normals, charts, q=0.3, cut=4.0)
    assert len(sheets) == 2
    true = (np.abs(points[:, 2] - 0.2 * upper) <= 3 * noise) & (np.abs(edge) > 3 * spacing)
    for sheet in sheets:
        assert len(np.unique(upper[sheet.core[true[sheet.core]]])) == 1


def test_a_crease_and_a_saddle_stay_one_sheet():
    # where the plain links find one sheet, they are taken again with the planes agreeing in
    # slope; the crease's faces (slopes -0.4 and 0.4) part by 3.4 noise sigmas one spacing from
    # the point, below the cut of 4, and the saddle's planes turn slowly
    rng = np.random.default_rng(9)
    g = np.linspace(-1, 1, N_SIDE)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    for z in (0.4 * np.abs(x - 0.1), 0.5 * (x**2 - y**2)):
        points = np.column_stack([x, y, z + rng.normal(0, SIGMA, len(z))])
        normals = estimate_normals(points)
        charts = split_charts(points, normals, max_points=len(points), q=0.25)
        assert len(split_sheets(points, normals, charts, q=0.25, cut=4.0)) == len(charts)


def test_the_filter_keeps_a_step_sharp_and_its_neighbours():
    # one smooth network drew a ramp over 3-4 spacings, flagged the true points next to the
    # step (beyond its rejection point) and kept the ghosts on the ramp; the sheets are fitted
    # separately, so the fitted step is as sharp as the sampling allows
    rng = np.random.default_rng(8)
    points, upper, ghost = step_grid(rng, n_ghosts=N_SIDE // 2)
    result = filter_points(points, rng=np.random.default_rng(0), q=0.25, settings=FAST)
    far = ghost & (np.minimum(points[:, 2], STEP - points[:, 2]) >= 5 * SIGMA)
    assert np.mean(~result.inlier[far]) >= 0.95
    assert np.mean(~result.inlier[~ghost]) <= 0.01
    s = np.linspace(-0.3, 0.3, 601)
    probe = np.column_stack([0.05 + s, np.full_like(s, 0.1), np.full_like(s, STEP / 2)])
    level = project_on_surface(result, probe)[:, 2] / STEP
    rising = s[(level > 0.1) & (level < 0.9)]
    assert rising.size == 0 or np.ptp(rising) <= SPACING
    # the transition lies between the last sample of the low side and the first of the high one
    assert abs(s[np.argmin(np.abs(level - 0.5))]) <= SPACING


def front_ghost_grid(rng):
    """:func:`step_grid` with a mixed pixel at every site of the high level's first column, at
    heights 0.6-0.85 of the step (4-8 sigma below it). Returns points, upper, ghost."""
    points, upper, ghost = step_grid(rng)
    front = upper & (points[:, 0] - 0.05 <= SPACING)
    ghost[front] = True
    points[front, 2] = rng.uniform(0.6, 0.85, front.sum()) * STEP
    return points, upper, ghost


def test_points_a_few_noise_scales_off_their_sheet_do_not_train_it():
    # the high sheet's front column is all ghosts a few sigma below its level: a network there
    # has no inner points to hold it and bent down to them (a ramp over 2-3 spacings). Ghosts
    # off any surface and 2.5-12 noise scales off their sheet's inner plane do not train it;
    # those within 4 sigma of their own local plane count as on a surface and still do. Of the
    # ghosts 4-10 sigma off their sheet's level, 54-85 % per draw were left out on seeds 9-14;
    # no true point was
    between_ghosts, left_out = 0, 0
    for seed in (9, 10, 11):
        points, upper, ghost = front_ghost_grid(np.random.default_rng(seed))
        normals = estimate_normals(points)
        charts = split_charts(points, normals, max_points=len(points), q=0.25)
        sheets = split_sheets(points, normals, charts, q=0.25, cut=4.0)
        assert len(sheets) == 2
        for sheet in sheets:
            level = STEP * np.median(upper[sheet.members[~ghost[sheet.members]]])
            gap = np.abs(points[sheet.members, 2] - level)
            between = ghost[sheet.members] & (gap > 4 * SIGMA) & (gap < 10 * SIGMA)
            between_ghosts += between.sum()
            left_out += np.sum(~sheet.trained[between])
            assert np.mean(~sheet.trained[~ghost[sheet.members]]) <= 0.02
    assert between_ghosts >= 3 * N_SIDE // 2  # most of the columns' ghosts
    assert left_out >= 0.5 * between_ghosts


@pytest.mark.slow
def test_a_column_of_ghosts_below_the_high_levels_front_does_not_bend_its_fit():
    # trained on its ghosts as well, the high sheet's network followed them down: its fit at
    # the front (one spacing beyond the level's first true column), in the median over the
    # column, lay below 0.95 of the step on 31 of 40 draws (0.75-1.03, median draw 0.87); one
    # noise sigma is 0.05 of it. Without the ghosts off any surface, below 0.95 on 7 of the 40
    # (0.89-1.02): the ghosts linked into the sheet through the local planes that their column
    # tilts still trained it, 1.5-2 sigma down (on the true points only, 0.99-1.01 on those
    # draws). Without those as well, on 1 (0.94-1.02, median 0.998). Within one sigma of the
    # level in the median of five draws: three or more of five below it at 1 / 40 is a 0.02 %
    # chance, at 7 / 40 a 4 % one, at 31 / 40 a 92 % one
    levels = []
    for seed in range(10, 15):
        points, upper, ghost = front_ghost_grid(np.random.default_rng(seed))
        result = filter_points(points, rng=np.random.default_rng(0), q=0.25, settings=FAST)
        front = upper & ghost
        probe = np.column_stack([points[front, :2], np.full(front.sum(), STEP / 2)])
        levels.append(np.median(project_on_surface(result, probe)[:, 2] / STEP))
    assert np.median(levels) >= 1 - SIGMA / STEP, levels


def test_charts_split_side_by_side_give_the_same_sheets_and_normals():
    rng = np.random.default_rng(11)
    grids = [step_grid(rng, n_ghosts=N_SIDE // 2)[0] for _ in range(3)]
    points = np.concatenate([grid + [0.0, 3.0 * i, 0.0] for i, grid in enumerate(grids)])  # three steps apart
    normals = estimate_normals(points)
    np.testing.assert_array_equal(estimate_normals(points, workers=2), normals)
    charts = split_charts(points, normals, max_points=len(grids[0]), q=0.25)
    alone = split_sheets(points, normals, charts, q=0.25, cut=4.0)
    side_by_side = split_sheets(points, normals, charts, q=0.25, cut=4.0, workers=3)
    assert len(alone) > len(charts)  # some charts hold the step
    assert len(side_by_side) == len(alone)
    for a, b in zip(alone, side_by_side):
        for name in ("members", "core", "trained"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
