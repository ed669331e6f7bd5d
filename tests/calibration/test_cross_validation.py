"""Cross-validation: halves of the views judged against their own covariances, pooled over four
splits, systematic errors flagged.

Simulated corners of the default ChArUco cube seen by two cameras (0.1 px noise). A clean session
must give a ratio near 1; a corner bias or a bent target, which the model does not have, must
give a ratio above RATIO_WARN and a one-line warning naming the camera.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scanrig.calibration.bundle import Problem, State, bundle_adjust, pack, unpack
from scanrig.calibration.cross_validation import (
    CAUSES,
    RATIO_WARN,
    SPLITS,
    CameraCrossValidation,
    CrossValidation,
    _projection_jacobian,
    combine_splits,
    compare_halves,
    cross_validation_warnings,
    split_halves,
)
from scanrig.calibration.init import initialise
from scanrig.calibration.pipeline import _solve_half, calibrate
from scanrig.calibration.synthetic import DETECTABLE_SQUARE_PX, ring_cameras, simulate
from scanrig.calibration.uncertainty import covariance
from scanrig.targets import cube

SIGMA_PX = 0.1
N_SHOTS = 12
TARGET = cube()
#: Under the model the squared ratio is chi-square over >= 6 directions divided by their number:
#: 0.5-2 holds it with probability > 0.95 (the benchmark shows the spread over seeds).
CLEAN_RATIO_RANGE = (0.5, 2.0)
#: Injected corner bias: 0.3 px towards the imaged centre of the board, at the board's edge.
BIAS_PX = 0.3
#: Injected flex: each cube face bowed by 1 mm at its middle (a parabola along its x axis).
FLEX_M = 0.001
#: The pixel-space and parameter-space chi-square of the reference camera differ only by the
#: projection's second-order terms at the halves' (0.1-1 px apart) intrinsics: ~1e-4 relative.
CHI2_RTOL = 1e-2
#: A half's intrinsics error less its linearised least-squares image of the noise, in its sigmas:
#: second order in the errors (largest 0.034 in this session, 0.11 in the 20-shot session with
#: the benchmark's largest ratios). A solve stopped short of the minimum or a wrong Jacobian shows
#: as a sizeable fraction of a sigma.
NONLINEAR_SIGMAS = 0.1
#: A half solved from the full solution against one initialised from scratch, in the latter's
#: sigmas: both stop at the solver's tolerance (a step gaining < 1e-10 of the cost, at most ~1e-3
#: sigma); 6e-6 measured here.
WARM_START_SIGMAS = 1e-3


@pytest.fixture(scope="module")
def session():
    rng = np.random.default_rng(0)
    cameras = ring_cameras(2, rng=rng)
    return simulate(cameras, TARGET, N_SHOTS, SIGMA_PX, rng, cover=True, min_square_px=DETECTABLE_SQUARE_PX)


def _cv_warnings(result) -> list[str]:
    return [w for w in result.warnings if "x their stated sigma" in w]


@pytest.fixture(scope="module")
def halves(session) -> list:
    """Bundle adjustments of the even and the odd shots of the session, apart, each initialised
    from scratch."""
    obs, models = session.obs, {c.name: c.model for c in session.cameras}
    out = []
    for shots in split_halves(len(obs.shot_names), SPLITS["odd/even"]):
        sub = obs.subset(np.isin(obs.shot, shots))
        init = initialise(sub, TARGET, models)
        out.append(bundle_adjust(sub, TARGET, init.cameras, init.world_from_target, init.reference_shot))
    return out


def _biased(obs):
    """Observations moved towards the centre of their board's image, ``BIAS_PX`` at its farthest corner."""
    key = (obs.camera * len(obs.shot_names) + obs.shot) * len(TARGET.boards) + TARGET.board_of(obs.point_id)
    _, view = np.unique(key, return_inverse=True)
    count = np.bincount(view)
    centre = np.stack([np.bincount(view, obs.uv[:, k]) / count for k in range(2)], axis=1)[view]
    offset = obs.uv - centre
    reach = np.zeros(len(count))
    np.maximum.at(reach, view, np.linalg.norm(offset, axis=1))
    return dataclasses.replace(obs, uv=obs.uv - BIAS_PX * offset / reach[view, None])


def _bent(sim):
    """Observations of a target whose faces are bowed by ``FLEX_M`` (calibrated as if flat)."""
    obs = sim.obs
    flat, board = TARGET.lookup(obs.point_id)
    bent = flat.copy()
    for k, b in enumerate(TARGET.boards):
        rows = board == k
        p_board = b.target_from_board.inverse().apply(flat[rows])
        lo, hi = b.points_board.min(axis=0), b.points_board.max(axis=0)
        x = (p_board[:, 0] - 0.5 * (lo[0] + hi[0])) / (0.5 * (hi[0] - lo[0]))
        p_board[:, 2] += FLEX_M * (1.0 - x ** 2)
        bent[rows] = b.target_from_board.apply(p_board)
    uv = obs.uv.copy()
    for s, pose in enumerate(sim.world_from_target):
        for c, cam in enumerate(sim.cameras):
            rows = (obs.shot == s) & (obs.camera == c)
            uv[rows] += cam.project(pose.apply(bent[rows])) - cam.project(pose.apply(flat[rows]))
    return dataclasses.replace(obs, uv=uv)


def test_projection_jacobian_matches_finite_differences(session):
    """dq/dx of points fixed in the reference camera's frame, the reference pose included."""
    init = initialise(session.obs, TARGET, {c.name: c.model for c in session.cameras})
    result = bundle_adjust(session.obs, TARGET, init.cameras, init.world_from_target, init.reference_shot)
    p_ref = np.array([[0.05, -0.03, 0.8], [-0.1, 0.08, 0.9]])
    step = 1e-7                                     # central differences: truncation ~1e-14 relative
    for camera in (0, 1):
        _, G, cols = _projection_jacobian(result, camera, 0, p_ref)
        for j, col in enumerate(cols):
            q = []
            for sign in (1, -1):
                x = result.x.copy()
                x[col] += sign * step
                moved = dataclasses.replace(result, state=unpack(x, result.layout, result.state))
                q.append(_projection_jacobian(moved, camera, 0, p_ref)[0])
            numeric = (q[0] - q[1]) / (2 * step)
            np.testing.assert_allclose(G[:, :, j], numeric, rtol=1e-5, atol=1e-4)
    # The reference camera sees the points in its own frame: only its intrinsics can move them.
    _, G, cols = _projection_jacobian(result, 0, 0, p_ref)
    assert len(cols) == len(result.state.cameras[0].params)


def test_ratio_is_the_chi_square_of_the_halves_intrinsics(halves):
    """The reference camera's points are fixed in its own frame, so only its intrinsics move them:
    with every intrinsic direction seen, ``ratio² dof`` is the chi-square of the halves' intrinsics
    difference against ``Σ_odd + Σ_even``, the statistic whose spread the acceptance relies on."""
    uncertainties = [covariance(h) for h in halves]
    check = compare_halves(halves[0], halves, [u.covariance for u in uncertainties],
                           {"cam0": 0.8, "cam1": 0.8}).cameras["cam0"]
    cols = [h.layout.intrinsics[0] for h in halves]
    diff = halves[1].x[cols[1]] - halves[0].x[cols[0]]
    cov = sum(u.covariance[np.ix_(c, c)] for u, c in zip(uncertainties, cols))
    chi2 = diff @ np.linalg.solve(cov, diff)
    print(f"cam0: ratio² dof {check.ratio ** 2 * check.dof:.4f} over {check.dof}, intrinsics chi-square {chi2:.4f}")
    assert check.dof == len(diff)
    assert check.ratio ** 2 * check.dof == pytest.approx(chi2, rel=CHI2_RTOL)


def test_a_camera_with_nothing_free_is_not_judged(session):
    """Reference camera with its intrinsics held fixed: nothing can differ between the halves, so
    there is no ratio (and no warning) rather than round-off read as data."""
    names = tuple(session.cameras[0].param_names)
    result = calibrate(session.obs, TARGET, "opencv5", fixed_params={"cam0": names})
    check = result.cross_validation.cameras["cam0"]
    assert check.dof == 0 and np.isnan(check.ratio)
    assert not any(w.startswith("cam0:") for w in _cv_warnings(result))


@pytest.mark.slow
def test_clean_halves_agree_with_their_uncertainty(session):
    result = calibrate(session.obs, TARGET, "opencv5")
    cv = result.cross_validation
    print("clean corners: ratio", {name: round(check.ratio, 2) for name, check in cv.cameras.items()})
    assert cv.reference_camera == "cam0"
    for name, check in cv.cameras.items():
        assert check.n_points > 100, name          # the cube covers a good part of every image
        assert check.dof >= 6, name
        assert CLEAN_RATIO_RANGE[0] < check.ratio < CLEAN_RATIO_RANGE[1], name
    assert _cv_warnings(result) == []


def _largest_split_ratios(cv) -> dict:
    """``camera -> largest ratio over the splits``."""
    return {name: max(cameras[name].ratio for cameras in cv.splits.values()) for name in cv.cameras}


@pytest.mark.slow
def test_corner_bias_is_flagged(session):
    result = calibrate(_biased(session.obs), TARGET, "opencv5")
    flagged = _cv_warnings(result)
    ratios = _largest_split_ratios(result.cross_validation)
    print(f"{BIAS_PX} px corner bias: largest split ratio", {name: round(r, 2) for name, r in ratios.items()})
    assert any(r > RATIO_WARN for r in ratios.values()), ratios
    assert sorted(w.split(":")[0] for w in flagged) == sorted(n for n, r in ratios.items() if r > RATIO_WARN)
    assert all(w.count("\n") == 0 and "pooled over the 4 splits into halves" in w for w in flagged)


@pytest.mark.slow
def test_board_flex_is_flagged(session):
    result = calibrate(_bent(session), TARGET, "opencv5")
    ratios = {name: check.ratio for name, check in result.cross_validation.cameras.items()}
    print(f"{FLEX_M * 1000:g} mm face flex: ratio", {name: round(r, 2) for name, r in ratios.items()})
    assert all(r > RATIO_WARN for r in ratios.values()), ratios
    assert len(_cv_warnings(result)) == len(ratios)


def _truth_in_gauge(sim, half):
    """The simulated truth as the parameter vector of ``half``: its world is the target at its
    reference shot (the active shot whose pose is not solved)."""
    layout = half.layout
    ref = next(s for s, (active, pose) in enumerate(zip(layout.shot_active, layout.shot_pose))
               if active and pose is None)
    world_from_ref = sim.world_from_target[ref]
    state = State([c.with_pose(c.cam_from_world @ world_from_ref) for c in sim.cameras],
                  [world_from_ref.inverse() @ pose if active else None
                   for pose, active in zip(sim.world_from_target, layout.shot_active)])
    return pack(state, layout), state


def test_halves_errors_are_the_injected_noise_carried_linearly(session, halves):
    """Each half's intrinsics error is the least-squares image of its injected noise, ``-(JᵀJ)⁻¹ Jᵀ r``
    with the Jacobian and the residuals at the truth: the solver reaches the minimum and the
    problem is linear at the noise's scale. With i.i.d. Gaussian corners the errors are then
    Gaussian with the covariance the halves state, and ``ratio² dof`` chi-square: a large ratio
    on such corners is a tail draw of the noise, not a wrong sigma."""
    for parity, half in enumerate(halves):
        sub = half.obs
        assert half.inliers.all()
        x_true, state_true = _truth_in_gauge(session, half)
        p_target, _ = TARGET.lookup(sub.point_id)
        r, J = Problem(sub, p_target, half.layout, state_true, np.sqrt(sub.weight))(x_true, True)
        JtJ = (J.T @ J).toarray()
        linear = -np.linalg.solve(JtJ, J.T @ r)
        std = np.sqrt(np.diag(covariance(half).covariance))
        for index in half.layout.intrinsics:
            remainder = (half.x[index] - x_true[index] - linear[index]) / std[index]
            print(f"half {parity}: non-linear remainder of the intrinsics, sigmas: {np.abs(remainder).max():.4f}")
            assert np.abs(remainder).max() < NONLINEAR_SIGMAS


def test_splits_are_balanced_orthogonal_contrasts():
    """Every shot is in one half of each split, the halves are equal to within a shot, the
    splits' ±1 contrasts are orthogonal over 8 shots, and the last split is the session's first
    half against its second."""
    for n_shots in (11, 12):
        for split in SPLITS.values():
            half0, half1 = split_halves(n_shots, split)
            np.testing.assert_array_equal(np.sort(np.concatenate([half0, half1])), np.arange(n_shots))
            assert abs(len(half0) - len(half1)) <= 1
    contrasts = np.array([np.where(split.half_of(8) == 0, 1, -1) for split in SPLITS.values()])
    np.testing.assert_array_equal(contrasts @ contrasts.T, 8 * np.eye(len(SPLITS)))
    np.testing.assert_array_equal(split_halves(7, SPLITS["first/second halves"])[0], [0, 1, 2, 3])


def _check(ratio, dof, n_points, measured_px=1.0, predicted_px=1.0, max_px=2.0):
    return CameraCrossValidation(measured_px, predicted_px, max_px, n_points, ratio, dof)


def test_pooled_check_sums_chi_square_and_directions():
    """The pooled ratio is sqrt(sum chi2 / sum dof), the pixel figures RMS over every split's points;
    a camera no split could judge stays None, a split without that camera does not count."""
    per_split = {"odd/even": CrossValidation({"a": _check(2.0, 9, 100, 3.0, 1.0), "b": None}, "a"),
                 "pairs": CrossValidation({"a": _check(1.0, 9, 300, 1.0, 2.0, 5.0), "b": None}, "a"),
                 "staggered pairs": CrossValidation({"a": None, "b": None}, "a")}
    cv = combine_splits(per_split)
    pooled = cv.cameras["a"]
    assert pooled.ratio == pytest.approx(np.sqrt((4.0 * 9 + 1.0 * 9) / 18))
    assert (pooled.dof, pooled.n_points, pooled.max_px) == (18, 400, 5.0)
    assert pooled.measured_px == pytest.approx(np.sqrt((100 * 9.0 + 300 * 1.0) / 400))
    assert pooled.predicted_px == pytest.approx(np.sqrt((100 * 1.0 + 300 * 4.0) / 400))
    assert cv.cameras["b"] is None and cv.reference_camera == "a"
    assert cv.splits["odd/even"]["a"] is per_split["odd/even"].cameras["a"]


def test_warning_names_the_split_whose_halves_differ_most():
    """One line per camera whose ratio exceeds RATIO_WARN in some split, naming the split with the
    largest ratio and giving the pooled one; none where every split is at or below it."""
    high, higher, low = _check(RATIO_WARN + 0.1, 9, 100), _check(RATIO_WARN + 1.0, 6, 50), _check(RATIO_WARN, 9, 100)
    splits = {"odd/even": {"a": high, "b": low}, "pairs": {"a": low, "b": low},
              "staggered pairs": {"a": None, "b": low}, "first/second halves": {"a": higher, "b": low}}
    cv = combine_splits({name: CrossValidation(cameras, "a") for name, cameras in splits.items()})
    lines = cross_validation_warnings(cv)
    pooled = cv.cameras["a"]
    assert [w.split(": its sigmas")[0] for w in lines] == [
        f"a: the first and second halves of the shots differ by {RATIO_WARN + 1.0:.1f} x their stated sigma "
        f"(6 directions, RMS 1 px, predicted 1 px); pooled over the 3 splits into halves {pooled.ratio:.1f} x "
        f"({pooled.dof} directions)"]
    assert "views taken in sequence" in lines[0]
    one_split = CrossValidation({"a": high}, "a")
    assert cross_validation_warnings(one_split)[0].startswith(
        f"a: the odd and even shots differ by {RATIO_WARN + 0.1:.1f} x their stated sigma (9 directions")


def test_halves_started_from_the_full_solution_reach_their_own_minimum(session, halves):
    """A half solved from the full solution (no initialisation, the full solution's corners) is the
    one solved from scratch, to a small fraction of its sigma: the warm start saves time only."""
    full = calibrate(session.obs, TARGET, "opencv5", cross_validate=False)
    fixed = {c.name: () for c in session.cameras}
    for shots, cold in zip(split_halves(N_SHOTS, SPLITS["odd/even"]), halves):
        warm = _solve_half(full, shots, fixed)
        std = np.sqrt(np.diag(covariance(cold).covariance))
        for warm_cols, cold_cols in zip(warm.layout.intrinsics, cold.layout.intrinsics):
            error = np.abs(warm.x[warm_cols] - cold.x[cold_cols]) / std[cold_cols]
            print(f"warm - cold intrinsics, sigmas: {error.max():.1e}")
            assert error.max() < WARM_START_SIGMAS


def test_a_split_whose_half_is_too_small_is_left_out(session):
    """Six shots: the pairs split's halves have 4 and 2 shots (fewer than 3), so only odd/even,
    staggered pairs and first/second halves count, and the pooled check is theirs."""
    six = session.obs.subset(session.obs.shot < 6)
    cv = calibrate(six, TARGET, "opencv5").cross_validation
    assert list(cv.splits) == ["odd/even", "staggered pairs", "first/second halves"]
    for name, check in cv.cameras.items():
        parts = [cameras[name] for cameras in cv.splits.values()]
        assert check.dof == sum(p.dof for p in parts)
        assert check.ratio ** 2 * check.dof == pytest.approx(sum(p.ratio ** 2 * p.dof for p in parts))


def test_summary_lists_every_splits_ratio_and_the_causes_when_one_split_is_high():
    """summary.txt: per camera the pooled figures and each split's ratio; the causes once some
    split's ratio exceeds RATIO_WARN, even when the pooled one does not."""
    from scanrig.calibration.summary import _cross_validation_lines

    splits = {"odd/even": {"a": _check(1.0, 9, 100)}, "first/second halves": {"a": _check(RATIO_WARN + 0.5, 4, 50)}}
    cv = combine_splits({name: CrossValidation(cameras, "a") for name, cameras in splits.items()})
    assert cv.cameras["a"].ratio < RATIO_WARN
    lines = _cross_validation_lines(cv)
    assert lines[1].endswith(f"(ratio {cv.cameras['a'].ratio:.2f} over 13 directions; per split: odd/even 1.00, "
                             f"first/second halves {RATIO_WARN + 0.5:.2f})")
    assert lines[-len(CAUSES):] == [f"  - {cause}" for cause in CAUSES]
    quiet = combine_splits({"odd/even": CrossValidation({"a": _check(1.0, 9, 100)}, "a")})
    assert not any("Likely causes" in line for line in _cross_validation_lines(quiet))
