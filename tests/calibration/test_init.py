"""Initialisation: boards cut to a line by the image border are skipped, and covering poses."""

from __future__ import annotations

import numpy as np

from scanrig.calibration.init import _plane_usable, initialise
from scanrig.calibration.observations import Observations
from scanrig.calibration.synthetic import covering_target_poses, ring_cameras, simulate
from scanrig.targets import cube


def _cut_to_one_row(obs, target, camera: int):
    """Keep, in every view of ``camera``, only one row (collinear points) of each board it sees."""
    keep = np.ones(len(obs), bool)
    rows = np.flatnonzero(obs.camera == camera)
    board = target.board_of(obs.point_id[rows])
    y = np.round(target.points_on_board(obs.point_id[rows])[:, 1], 6)
    for s in np.unique(obs.shot[rows]):
        for b in np.unique(board[obs.shot[rows] == s]):
            sel = (obs.shot[rows] == s) & (board == b)
            keep[rows[sel & (y != np.median(y[sel]))]] = False
    return obs.subset(keep)


def test_plane_usable_rejects_collinear_points():
    xy = np.column_stack([np.arange(7) * 0.025, np.zeros(7)])
    uv = 100 + 40 * xy / 0.025
    assert not _plane_usable(xy, uv)
    grid = np.array([[i, j] for i in range(3) for j in range(3)], float) * 0.025
    assert _plane_usable(grid, 300 + 1500 * grid + 0.01 * grid[:, ::-1])


def test_boards_cut_to_one_row_are_skipped_not_fatal():
    """One camera sees only one row of some boards (as at the image border): init still works."""
    rng = np.random.default_rng(3)
    cams = ring_cameras(3, rng=rng)
    target = cube()
    sim = simulate(cams, target, 8, 0.1, rng, max_shift_m=0.15)
    obs = sim.obs
    # Camera 0: shot 0 intact, all other shots only one (collinear) row per board.
    mask = (obs.camera == 0) & (obs.shot > 0)
    cut = _cut_to_one_row(obs.subset(mask), target, 0)
    parts = obs.subset(~mask)
    obs = Observations(np.concatenate([parts.camera, cut.camera]), np.concatenate([parts.shot, cut.shot]),
                       np.concatenate([parts.point_id, cut.point_id]), np.concatenate([parts.uv, cut.uv]),
                       np.concatenate([parts.weight, cut.weight]), obs.camera_names, obs.shot_names,
                       obs.image_sizes)
    init = initialise(obs, target, {c.name: c.model for c in cams})
    f_true = cams[0].params[0]
    assert abs(init.cameras[0].params[0] / f_true - 1) < 0.05


def test_covering_poses_spread_over_the_images():
    rng = np.random.default_rng(0)
    cams = ring_cameras(3, rng=rng)
    target = cube()
    poses = covering_target_poses(cams, target, 20, rng)
    assert len(poses) == 20
    sim = simulate(cams, target, 20, 0.1, np.random.default_rng(1), cover=True)
    counts = sim.obs.view_counts()
    assert np.all((counts >= 12).sum(axis=0) >= 2)          # every shot seen by >= 2 cameras
    for c, cam in enumerate(cams):
        uv = sim.obs.uv[sim.obs.camera == c]
        # Observations reach every quarter of the image and near its corners.
        for qx in (0, 1):
            for qy in (0, 1):
                inq = ((uv[:, 0] >= qx * cam.width / 2) & (uv[:, 0] < (qx + 1) * cam.width / 2)
                       & (uv[:, 1] >= qy * cam.height / 2) & (uv[:, 1] < (qy + 1) * cam.height / 2))
                assert inq.sum() > 50
        assert np.ptp(uv[:, 0]) > 0.85 * cam.width and np.ptp(uv[:, 1]) > 0.85 * cam.height
