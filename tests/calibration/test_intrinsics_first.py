"""Intrinsics first, then the rig: priors and fixed intrinsics in the joint solve (synthetic truth)."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.calibration.bundle import (
    Layout,
    PriorRows,
    Problem,
    State,
    bundle_adjust,
    pack,
)
from scanrig.calibration.init import initialise
from scanrig.calibration.synthetic import ring_cameras, simulate
from scanrig.calibration.uncertainty import covariance
from scanrig.targets import cube

#: Injected detection noise, pixels.
SIGMA_PX = 0.1
#: Estimates within this many reported sigmas of the truth (a 5-sigma miss of any of the ~10
#: checked parameters has probability ~6e-6).
Z_MAX = 5.0
#: Prior sigmas of fx fy cx cy (px) and k1 k2 p1 p2 k3: loose enough that the data matter, tight
#: enough that the prior does too.
PRIOR_STD = np.array([3.0, 3.0, 2.0, 2.0, 0.01, 0.02, 5e-4, 5e-4, 0.05])
#: The prior rows are scaled with the pixel sigma of the first of the two final solves; the second
#: moves the parameters by a small fraction of their sigma, so the measured pixel sigma changes by
#: far less than this (relative).
PRIOR_SCALE_RTOL = 1e-2


@pytest.fixture(scope="module")
def rig_views():
    """Two cameras, 4 shots of the cube: few enough views that a prior visibly helps."""
    rng = np.random.default_rng(31)
    cams = ring_cameras(2, rng=rng)
    target = cube()
    sim = simulate(cams, target, 4, SIGMA_PX, rng, max_shift_m=0.15)
    init = initialise(sim.obs, target, {c.name: "opencv5" for c in cams})
    return rng, cams, target, sim, init


def _prior_of(truth, rng):
    """Prior on camera 0: the truth moved by one draw of the prior's own noise."""
    return {truth.name: (truth.params + rng.normal(scale=PRIOR_STD), PRIOR_STD)}


def test_prior_rows_jacobian_matches_finite_differences(rig_views):
    rng, cams, target, sim, _ = rig_views
    layout = Layout.build(cams, np.ones(4, bool), 0, {cams[0].name: ("k3",)})
    prior = PriorRows.build(cams, layout, _prior_of(cams[0], rng))
    assert len(prior.cols) == len(PRIOR_STD) - 1          # k3 is held fixed: no prior row for it
    state = State(cams, sim.world_from_target)
    p_target, _ = target.lookup(sim.obs.point_id)
    problem = Problem(sim.obs, p_target, layout, state, np.sqrt(sim.obs.weight), prior, prior_scale_px=0.3)
    x = pack(state, layout)
    r, J = problem(x, True)
    assert r.shape == (2 * len(sim.obs) + len(prior.cols),)
    J = J.toarray()
    # Central differences, relative step 1e-6: truncation ~1e-12 relative, round-off ~1e-10.
    for k in list(prior.cols) + list(rng.choice(layout.size, 10, replace=False)):
        h = 1e-6 * max(1.0, abs(x[k]))
        dx = np.zeros_like(x)
        dx[k] = h
        numeric = (problem(x + dx, False) - problem(x - dx, False)) / (2 * h)
        np.testing.assert_allclose(J[:, k], numeric, rtol=1e-5, atol=1e-5 * np.abs(numeric).max())


def test_prior_enters_the_covariance_with_its_own_variance(rig_views):
    rng, cams, target, sim, init = rig_views
    priors = _prior_of(cams[0], rng)
    result = bundle_adjust(sim.obs, target, init.cameras, init.world_from_target, init.reference_shot, priors=priors)
    n_pixel_rows = 2 * int(result.inliers.sum())
    J_prior = result.jacobian.toarray()[n_pixel_rows:]
    assert J_prior.shape[0] == len(PRIOR_STD)
    # covariance = sigma² (JᵀJ)⁻¹, so the prior rows add (J_priorᵀ J_prior) / sigma² = 1 / std².
    precision = np.diag(J_prior.T @ J_prior)[result.layout.intrinsics[0]] / result.sigma_px ** 2
    np.testing.assert_allclose(precision, 1.0 / PRIOR_STD ** 2, rtol=2 * PRIOR_SCALE_RTOL)
    without = bundle_adjust(sim.obs, target, init.cameras, init.world_from_target, init.reference_shot)
    std_with = covariance(result).params_std[cams[0].name]
    std_without = covariance(without).params_std[cams[0].name]
    # Information adds: the posterior is tighter than either the prior or the views alone.
    assert np.all(std_with < PRIOR_STD) and np.all(std_with < std_without)
    z = (result.state.cameras[0].params - cams[0].params) / std_with
    print(f"prior: z of camera 0's intrinsics {np.round(z, 2)}; sigma fx with prior {std_with[0]:.3f} px, "
          f"views alone {std_without[0]:.3f} px, prior {PRIOR_STD[0]} px")
    assert np.all(np.abs(z) < Z_MAX)


def test_tight_prior_acts_as_fixed_intrinsics(rig_views):
    """A prior a million times tighter than the views reproduces the fixed-intrinsics solve."""
    _, cams, target, sim, init = rig_views
    start = [cams[0].with_pose(init.cameras[0].cam_from_world), init.cameras[1]]
    tight = {cams[0].name: (cams[0].params, 1e-6 * PRIOR_STD)}
    with_prior = bundle_adjust(sim.obs, target, start, init.world_from_target, init.reference_shot, priors=tight)
    fixed = bundle_adjust(sim.obs, target, start, init.world_from_target, init.reference_shot,
                          fixed_params={cams[0].name: cams[0].param_names})
    assert np.all(np.abs(with_prior.state.cameras[0].params - cams[0].params) < 1e-4 * PRIOR_STD)
    baseline = [np.linalg.norm(r.state.cameras[0].center_world - r.state.cameras[1].center_world)
                for r in (with_prior, fixed)]
    # Both solves leave camera 0's intrinsics within 1e-6 prior sigmas of the same values: the
    # baselines agree far below the micrometre.
    assert baseline[0] == pytest.approx(baseline[1], abs=1e-7)


def test_a_camera_with_known_intrinsics_needs_one_view_only():
    """The real 4-webcam rig with cam_1 seen in one frame only: refused without its intrinsics
    (two views of a board are needed to calibrate it), solved with them."""
    from scanrig.calibration.intrinsics_prior import KnownIntrinsics
    from scanrig.calibration.pipeline import calibrate
    from scanrig.errors import InputError
    from scanrig.targets import charuco
    from tests.calibration.test_real_data import _caliscope_observations
    from tests.cli.test_calibrate_intrinsics import caliscope_reference

    obs = _caliscope_observations()
    one_view = obs.subset((obs.camera != 1) | (obs.shot == obs.shot_names.index("60")))
    target = charuco((4, 5), 0.054, 0.0405, "DICT_4X4_1000")
    with pytest.raises(InputError, match=r"^camera 'cam_1': the target was found in 1 usable view\(s\); at least 2"):
        calibrate(one_view, target, "opencv5", cross_validate=False)
    reference = caliscope_reference()
    known = {name: KnownIntrinsics(reference[name], None, "camera_array.toml") for name in reference.names}
    result = calibrate(one_view, target, "opencv5", cross_validate=False, known_intrinsics=known)
    baseline = np.linalg.norm(result.rig["cam_1"].center_world - result.rig["cam_0"].center_world)
    baseline_ref = np.linalg.norm(reference["cam_1"].center_world - reference["cam_0"].center_world)
    sigma_m = np.linalg.norm(result.uncertainty.center_std_m["cam_1"])
    print(f"cam_0-cam_1 baseline from one view of cam_1: {1000 * (baseline - baseline_ref):+.1f} mm from the "
          f"rig's own, stated sigma of cam_1's centre {1000 * sigma_m:.1f} mm")
    np.testing.assert_array_equal(result.rig["cam_1"].params, reference["cam_1"].params)
    assert abs(baseline - baseline_ref) < 3 * sigma_m


def _board_poses(board, n: int, depth_m: float, tilt_deg: float, shift_m: float, rng) -> list:
    """``n`` poses of a board centred near the optical axis at ``depth_m``, tilted up to ``tilt_deg``."""
    from scipy.spatial.transform import Rotation

    from scanrig.geometry.transform import RigidTransform

    centre = np.array([board.size_m[0] / 2, board.size_m[1] / 2, 0.0])
    poses = []
    for k in range(n):
        R = Rotation.from_rotvec(np.deg2rad([tilt_deg * np.sin(k), tilt_deg * np.cos(1.7 * k), 5 * k])).as_matrix()
        t = np.array([*rng.uniform(-shift_m, shift_m, 2), depth_m]) - R @ centre
        poses.append(RigidTransform(R, t))
    return poses


@pytest.mark.slow
def test_rendered_rig_far_views_with_close_intrinsic_views(tmp_path, capsys):
    """Two rendered cameras that see the rig's board only far (4 shots at 1.2 m, 124 px wide,
    tilts up to 10 deg), each also with 5 close views in calibration_intrinsic/<camera>/: the rig
    solved from its views alone cannot fix the intrinsics; with the close views first, the
    intrinsics and the baseline come out within their stated sigmas of the truth, tighter."""
    from scipy.spatial.transform import Rotation

    from scanrig.calibration.synthetic import render_board
    from scanrig.cli.main import main
    from scanrig.geometry.camera import Camera
    from scanrig.geometry.transform import RigidTransform
    from scanrig.io.rig_file import load_rig_info
    from scanrig.io.session import write_image
    from scanrig.targets import chessboard, save_target

    rng = np.random.default_rng(41)
    target = chessboard((7, 5), 0.03)
    board = target.boards[0]
    truth = np.array([620.0, 620.0, 320.0, 240.0, -0.05, 0.02, 0.0, 0.0, 0.0])
    left = Camera("left", "opencv5", truth, 640, 480)
    right = Camera("right", "opencv5", truth + [5, 5, -4, 3, 0, 0, 0, 0, 0], 640, 480,
                   RigidTransform(Rotation.from_rotvec([0, -0.08, 0]).as_matrix(), np.array([-0.08, 0, 0])))
    save_target(target, tmp_path / "target.toml")
    for cam in (left, right):
        (tmp_path / "calibration" / cam.name).mkdir(parents=True)
    for k, world_from_board in enumerate(_board_poses(board, 4, 1.2, 10.0, 0.1, rng)):
        for cam in (left, right):
            img = render_board(board, cam, cam.cam_from_world @ world_from_board, 0.8, 2.0, rng, supersample=2)
            write_image(tmp_path / "calibration" / cam.name / f"{k:02d}.png", img)
    assert main(["calibrate", str(tmp_path), "--no-plots", "--no-cross-validate"]) == 0
    out = capsys.readouterr().out
    for cam in (left, right):
        assert f"{cam.name}: intrinsics not determined by these views (fx ±" in out
    alone, alone_info, _ = load_rig_info(tmp_path / "rig.toml")
    for cam in (left, right):
        folder = tmp_path / "calibration_intrinsic" / cam.name
        folder.mkdir(parents=True)
        for k, cam_from_board in enumerate(_board_poses(board, 5, 0.4, 30.0, 0.06, rng)):
            write_image(folder / f"{k:02d}.png", render_board(board, cam, cam_from_board, 0.8, 2.0, rng, supersample=2))
    (tmp_path / "rig.toml").unlink()
    assert main(["calibrate", str(tmp_path), "--no-plots", "--no-cross-validate", "--refine-intrinsics"]) == 0
    out = capsys.readouterr().out
    for cam in (left, right):      # k3 is what 5 views of a 7x5 board leave open
        assert f"calibration_intrinsic/{cam.name} (calibrated alone): {cam.name}: distortion not determined" in out
    first, first_info, _ = load_rig_info(tmp_path / "rig.toml")
    for label, rig, info in (("rig views alone", alone, alone_info), ("intrinsics first", first, first_info)):
        baseline = np.linalg.norm(rig["left"].center_world - rig["right"].center_world)
        fx_z = [(rig[c.name].params[0] - c.params[0]) / info[c.name]["params_std"][0] for c in (left, right)]
        print(f"{label}: fx sigma {info['left']['params_std'][0]:.2f} / {info['right']['params_std'][0]:.2f} px, "
              f"fx error in sigmas {np.round(fx_z, 2)}, baseline error {1000 * (baseline - 0.08):+.2f} mm")
    for cam in (left, right):
        std = np.array(first_info[cam.name]["params_std"])
        assert np.all(np.abs(first[cam.name].params[:4] - cam.params[:4]) <= Z_MAX * std[:4])
        assert np.all(std[:4] < np.array(alone_info[cam.name]["params_std"][:4]))


def test_undetermined_intrinsics_line_names_the_open_pinhole_parameters_in_their_order():
    from scanrig.calibration.intrinsics_prior import undetermined_intrinsics

    poorly = [("k3", 13.4, 51.0), ("cx", 10.0, 10.0), ("k1", 0.12, 11.0), ("fx", 11.0, 9.3)]
    assert undetermined_intrinsics("cam1", poorly) == (
        "cam1: intrinsics not determined by these views (fx ±11 px, cx ±10 px): calibrate them separately "
        "(calibration_intrinsic/cam1/ images, or --intrinsics FILE)")
    assert undetermined_intrinsics("cam1", poorly[::2]) is None             # distortion has its own line


def test_refined_intrinsics_far_from_their_prior_are_named(rig_views):
    """A prior from another lens (fx 10 prior sigmas off) is pulled back by the views and
    warned about; the truth as prior is not."""
    from scanrig.calibration.intrinsics_prior import KnownIntrinsics
    from scanrig.calibration.pipeline import calibrate

    _, cams, target, sim, _ = rig_views
    for offset, warned in ((0.0, False), (10.0 * PRIOR_STD[0], True)):
        prior = cams[0].with_params(cams[0].params + np.eye(len(PRIOR_STD))[0] * offset)
        known = {cams[0].name: KnownIntrinsics(prior, PRIOR_STD, "other.toml")}
        result = calibrate(sim.obs, target, "opencv5", cross_validate=False, known_intrinsics=known,
                           refine_intrinsics=True)
        lines = [w for w in result.warnings if "these views pull its intrinsics" in w]
        print(lines)
        assert len(lines) == int(warned)
        if warned:
            assert lines[0].startswith(f"{cams[0].name}: these views pull its intrinsics ")
            assert f"sigma from other.toml (fx {prior.params[0]:.6g} -> " in lines[0]
