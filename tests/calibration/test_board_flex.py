"""Board flex: a bent planar board is flagged when calibrated as flat, and estimated with ``flex = true``.

Simulated corners (no rendering) of a 0.5 m x 0.35 m ChArUco board (10 x 7 squares of 50 mm, a
foam board) seen by two cameras with 0.1 px noise, bent by ``FLEX_M``
(:func:`scanrig.targets.target.flex_shape`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scanrig.calibration.bundle import Layout, Problem, State, pack
from scanrig.calibration.cross_validation import RATIO_WARN
from scanrig.calibration.flex_check import flex_step
from scanrig.calibration.pipeline import calibrate
from scanrig.calibration.summary import format_summary, summary_dict
from scanrig.calibration.synthetic import DETECTABLE_SQUARE_PX, ring_cameras, simulate
from scanrig.errors import FileFormatError, InputError
from scanrig.targets import charuco, cube, load_target, target_to_toml
from scanrig.targets.target import flex_shape

SIGMA_PX = 0.1
N_SHOTS = 16
#: Injected flex (c_x, c_y), metres: 1 mm sag along the board's length, 0.4 mm across.
FLEX_M = np.array([1.0e-3, 0.4e-3])
#: Acceptance: the flex recovered within 0.1 mm.
FLEX_TOL_M = 1.0e-4
#: A flat board's estimated flex must lie within this many of its sigmas of zero (a 4-sigma miss
#: of either of the two terms has probability 1.3e-4).
Z_MAX = 4.0
RIGID = charuco((10, 7), 0.05, 0.0375)
FLEXIBLE = charuco((10, 7), 0.05, 0.0375, flex=True)


def _session(flex_m, seed=0):
    rng = np.random.default_rng(seed)
    cameras = ring_cameras(2, rng=rng)
    return simulate(cameras, RIGID, N_SHOTS, SIGMA_PX, rng, cover=True, min_square_px=DETECTABLE_SQUARE_PX,
                    flex_m=flex_m)


@pytest.fixture(scope="module")
def bent():
    return _session(FLEX_M)


def _cv_warnings(result) -> list[str]:
    return [w for w in result.warnings if "x their stated sigma" in w]


def _flex_warnings(result) -> list[str]:
    return [w for w in result.warnings if w.startswith("target: the board looks bent")]


def test_flex_shape_is_zero_at_the_grid_corners_and_sags_at_the_centre():
    board = RIGID.boards[0]
    grid = board.points_local
    lo, hi = grid.min(axis=0), grid.max(axis=0)
    corners = np.array([lo, hi, [lo[0], hi[1]], [hi[0], lo[1]]])
    np.testing.assert_allclose(flex_shape(board, corners), 0.0, atol=1e-12)
    np.testing.assert_allclose(flex_shape(board, [0.5 * (lo + hi)]), [[1.0, 1.0]])
    # Midpoint of the left edge: only the sag across (c_y) is left.
    np.testing.assert_allclose(flex_shape(board, [[lo[0], 0.5 * (lo[1] + hi[1])]]), [[0.0, 1.0]], atol=1e-12)


def test_jacobian_of_the_flex_terms_matches_finite_differences(bent):
    cams = bent.cameras
    layout = Layout.build(cams, np.ones(N_SHOTS, bool), 0, {}, flex=True)
    state = State(cams, bent.world_from_target, FLEX_M.copy())
    p_target, _ = RIGID.lookup(bent.obs.point_id)
    problem = Problem(bent.obs, p_target, layout, state, np.sqrt(bent.obs.weight),
                      flex_dir=FLEXIBLE.flex_directions(bent.obs.point_id))
    x = pack(state, layout)
    _, J = problem(x, True)
    J = J.toarray()
    # The flex terms and one shot's rotation (whose derivative now involves the bent point).
    shot = layout.shot_pose[3].start
    columns = [layout.flex.start, layout.flex.start + 1, shot, shot + 1, shot + 2]
    for k in columns:
        h = 1e-6 * max(1.0, abs(x[k]))      # central differences: truncation ~1e-12 relative
        dx = np.zeros_like(x)
        dx[k] = h
        numeric = (problem(x + dx, False) - problem(x - dx, False)) / (2 * h)
        np.testing.assert_allclose(J[:, k], numeric, rtol=1e-5, atol=1e-5 * np.abs(numeric).max())


@pytest.mark.slow
def test_bent_board_calibrated_as_flat_is_flagged(bent):
    result = calibrate(bent.obs, RIGID, "opencv5")
    ratios = {name: check.ratio for name, check in result.cross_validation.cameras.items()}
    print(f"{FLEX_M * 1000} mm flex, flex off: ratio", {name: round(r, 2) for name, r in ratios.items()})
    assert all(r > RATIO_WARN for r in ratios.values()), ratios
    assert len(_cv_warnings(result)) == len(ratios)
    assert "board_flex_m" not in summary_dict(result)
    # The one-step flex estimate from the flat solution finds the bend, and says so in one line.
    flex, sigma = flex_step(result.bundle, RIGID)
    print(f"one-step flex from the flat solution: {flex * 1000} ± {sigma * 1000} mm")
    np.testing.assert_allclose(flex, FLEX_M, atol=FLEX_TOL_M)
    (cx, cy), (sx, sy) = flex * 1000, sigma * 1000
    assert _flex_warnings(result) == [
        f"target: the board looks bent (sag at the centre along x {cx:.3f} ± {sx:.3f} mm, along y {cy:.3f} ± "
        f"{sy:.3f} mm, estimated from the flat-board solution): set flex = true in target.toml to estimate the "
        "bend, or use a flatter board"]


@pytest.mark.slow
def test_flex_true_recovers_the_bend_and_the_warning_goes(bent):
    result = calibrate(bent.obs, FLEXIBLE, "opencv5")
    flex, sigma = result.bundle.state.flex_m, result.uncertainty.flex_std_m
    ratios = {name: check.ratio for name, check in result.cross_validation.cameras.items()}
    print(f"flex on: {flex * 1000} ± {sigma * 1000} mm (truth {FLEX_M * 1000}); ratio",
          {name: round(r, 2) for name, r in ratios.items()})
    np.testing.assert_allclose(flex, FLEX_M, atol=FLEX_TOL_M)
    assert np.all(np.abs(flex - FLEX_M) < Z_MAX * sigma), (flex, sigma)
    assert _cv_warnings(result) == [] and _flex_warnings(result) == []
    summary = summary_dict(result)
    assert summary["format_version"] == 1
    np.testing.assert_array_equal(summary["board_flex_m"], flex)
    np.testing.assert_array_equal(summary["board_flex_std_m"], sigma)
    assert (f"board flex (sag at the centre): along x {flex[0] * 1000:.4f} ± {sigma[0] * 1000:.4f} mm, "
            f"along y {flex[1] * 1000:.4f} ± {sigma[1] * 1000:.4f} mm") in format_summary(result)


@pytest.mark.slow
def test_flat_board_with_flex_true_gives_zero_within_its_sigma():
    flat = _session(None, seed=1)
    result = calibrate(flat.obs, FLEXIBLE, "opencv5", cross_validate=False)
    flex, sigma = result.bundle.state.flex_m, result.uncertainty.flex_std_m
    print(f"flat board, flex on: {flex * 1000} ± {sigma * 1000} mm")
    assert np.all(np.abs(flex) < Z_MAX * sigma), (flex, sigma)
    assert np.all(sigma < FLEX_TOL_M)
    # Calibrated as flat: the one-step estimate agrees, and there is no warning.
    rigid = calibrate(flat.obs, RIGID, "opencv5", cross_validate=False)
    step, step_sigma = flex_step(rigid.bundle, RIGID)
    assert np.all(np.abs(step) < Z_MAX * step_sigma), (step, step_sigma)
    assert _flex_warnings(rigid) == []


def test_flex_on_a_cube_is_refused():
    with pytest.raises(InputError) as exc:
        cube(flex=True)
    assert str(exc.value) == ("flex = true needs a planar target (one board); a cube target has 6 rigidly "
                              "joined boards, whose bending is not modelled")


def test_flex_on_a_cube_in_target_toml_is_refused(tmp_path: Path):
    path = tmp_path / "target.toml"
    path.write_text('kind = "cube"\nedge_m = 0.2\nsquares = 7\nsquare_m = 0.025\nmarker_m = 0.01875\nflex = true\n')
    with pytest.raises(FileFormatError) as exc:
        load_target(path)
    assert str(exc.value) == (f"{path}: target: flex = true needs a planar target (one board); a cube target "
                              "has 6 rigidly joined boards, whose bending is not modelled")


def test_flex_must_be_a_boolean(tmp_path: Path):
    path = tmp_path / "target.toml"
    path.write_text(target_to_toml(RIGID) + "flex = 1\n")
    with pytest.raises(FileFormatError) as exc:
        load_target(path)
    assert str(exc.value) == f"{path}: target: flex must be true or false, got 1"


def test_target_toml_keeps_flex_and_leaves_a_rigid_board_unchanged(tmp_path: Path):
    assert "flex" not in target_to_toml(RIGID)
    path = tmp_path / "target.toml"
    path.write_text(target_to_toml(FLEXIBLE))
    loaded = load_target(path)
    assert loaded.flex is True and loaded.spec == FLEXIBLE.spec
