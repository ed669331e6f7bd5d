"""Joint bundle adjustment on synthetic observations with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.calibration.bundle import Layout, Problem, State, bundle_adjust, pack
from scanrig.calibration.init import initialise
from scanrig.calibration.pipeline import calibrate
from scanrig.calibration.synthetic import observe, ring_cameras, simulate
from scanrig.calibration.uncertainty import covariance
from scanrig.errors import InputError
from scanrig.geometry.transform import RigidTransform
from scanrig.targets import chessboard, cube

#: Injected detection noise, pixels.
SIGMA_PX = 0.1
#: Estimates must lie within this many reported sigmas of the truth (a 5-sigma miss of any of
#: ~40 checked parameters has probability ~2e-5).
Z_MAX = 5.0


def _errors(truth, est, unc):
    """Normalised errors (estimate - truth) / reported sigma: intrinsics and camera centres."""
    z = []
    for ct, ce in zip(truth, est):
        z.append((ce.params - ct.params) / unc.params_std[ct.name])
        z.append((ce.center_world - ct.center_world) / unc.center_std_m[ct.name])
    return np.concatenate(z)


def test_problem_jacobian_matches_finite_differences():
    rng = np.random.default_rng(11)
    cams = ring_cameras(2, rng=rng)
    target = cube()
    sim = simulate(cams, target, 3, SIGMA_PX, rng)
    layout = Layout.build(cams, np.ones(3, bool), 0, {})
    state = State(cams, sim.world_from_target)
    p_target, _ = target.lookup(sim.obs.point_id)
    problem = Problem(sim.obs, p_target, layout, state, np.sqrt(sim.obs.weight))
    x = pack(state, layout)
    r, J = problem(x, True)
    J = J.toarray()
    # Central differences with relative step 1e-6: truncation ~1e-12 relative, round-off ~1e-10.
    for k in rng.choice(layout.size, 25, replace=False):
        h = 1e-6 * max(1.0, abs(x[k]))
        dx = np.zeros_like(x)
        dx[k] = h
        numeric = (problem(x + dx, False) - problem(x - dx, False)) / (2 * h)
        np.testing.assert_allclose(J[:, k], numeric, rtol=1e-5, atol=1e-5 * np.abs(numeric).max())


def test_cube_three_cameras_recovers_truth_within_reported_sigma():
    rng = np.random.default_rng(5)
    cams = ring_cameras(3, rng=rng)
    target = cube()
    sim = simulate(cams, target, 12, SIGMA_PX, rng, max_shift_m=0.15)
    result = calibrate(sim.obs, target, "opencv5", cross_validate=False)
    assert result.bundle.outliers == [] or len(result.bundle.outliers) <= 2  # 5-sigma tail only
    # The measured residual scale matches the injected noise: sigma_hat / sigma ~ 1 ± 1/sqrt(2 dof).
    assert result.bundle.sigma_px == pytest.approx(SIGMA_PX, rel=0.1)
    z = _errors(cams, result.rig.cameras, result.uncertainty)
    assert np.abs(z).max() < Z_MAX
    for ct, ce in zip(cams, result.rig.cameras):
        angle = np.degrees(np.linalg.norm((ce.cam_from_world @ ct.cam_from_world.inverse()).rvec))
        assert angle < Z_MAX * np.sqrt(3) * result.uncertainty.rotation_std_deg[ct.name]


def test_single_simultaneous_view_of_cube():
    rng = np.random.default_rng(2)
    cams = ring_cameras(3, rng=rng, model="opencv4")
    target = cube()
    obs = observe(cams, target, [RigidTransform.identity()], SIGMA_PX, rng)
    result = calibrate(obs, target, "opencv4", cross_validate=False)
    z = _errors(cams, result.rig.cameras, result.uncertainty)
    assert np.abs(z).max() < Z_MAX
    assert result.rig.names == ["cam0", "cam1", "cam2"]


def test_normalised_errors_have_unit_spread_over_seeds():
    """Reported sigmas are honest: over 20 seeds the normalised errors have spread ~1."""
    target = chessboard((7, 5), 0.04)
    zs = []
    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        cams = ring_cameras(2, rng=rng, model="opencv4", spread_deg=20.0, elevation_deg=-65.0,
                            center_m=(0.16, 0.12, 0.0))
        sim = simulate(cams, target, 6, SIGMA_PX, rng, max_tilt_deg=40.0, max_shift_m=0.1)
        init = initialise(sim.obs, target, {c.name: c.model for c in cams})
        res = bundle_adjust(sim.obs, target, init.cameras, init.world_from_target, init.reference_shot,
                            robust=False)
        zs.append(_errors(cams, res.state.cameras, covariance(res)))
    spread = np.std(np.concatenate(zs))
    assert 0.7 < spread < 1.5, spread


def test_gross_outliers_are_rejected_and_reported():
    rng = np.random.default_rng(8)
    cams = ring_cameras(2, rng=rng, model="opencv4")
    target = cube()
    sim = simulate(cams, target, 6, SIGMA_PX, rng)
    uv = sim.obs.uv.copy()
    bad = rng.choice(len(uv), 6, replace=False)
    uv[bad] += rng.choice([-1, 1], size=(6, 2)) * 8.0          # 80 sigma errors
    obs = type(sim.obs)(sim.obs.camera, sim.obs.shot, sim.obs.point_id, uv, sim.obs.weight,
                        sim.obs.camera_names, sim.obs.shot_names, sim.obs.image_sizes)
    result = calibrate(obs, target, "opencv4", cross_validate=False)
    rejected = {(o.camera, o.shot, o.point_id) for o in result.bundle.outliers}
    planted = {(obs.camera_names[obs.camera[i]], obs.shot_names[obs.shot[i]], int(obs.point_id[i])) for i in bad}
    assert planted <= rejected
    assert len(rejected - planted) <= 2
    assert result.bundle.sigma_px == pytest.approx(SIGMA_PX, rel=0.15)


def test_disconnected_camera_graph_is_reported():
    rng = np.random.default_rng(4)
    cams = ring_cameras(2, rng=rng, model="opencv4")
    target = cube()
    sim = simulate(cams, target, 6, SIGMA_PX, rng)
    # cam0 keeps even shots only, cam1 odd shots only: no shot is seen by both.
    keep = (sim.obs.shot % 2) == sim.obs.camera
    with pytest.raises(InputError, match=r"camera graph is disconnected: cameras \['cam1'\] share no shot"):
        calibrate(sim.obs.subset(keep), target, "opencv4", cross_validate=False)


def test_too_few_views_and_unseen_target():
    rng = np.random.default_rng(6)
    cams = ring_cameras(2, rng=rng, model="opencv4")
    target = chessboard((7, 5), 0.04)
    cams = ring_cameras(2, rng=rng, model="opencv4", elevation_deg=-65.0, center_m=(0.16, 0.12, 0.0))
    sim = simulate(cams, target, 4, SIGMA_PX, rng)
    one_view = ~((sim.obs.camera == 1) & (sim.obs.shot > 0))
    with pytest.raises(InputError, match=r"camera 'cam1': the target was found in 1 usable view\(s\); at least 2"):
        calibrate(sim.obs.subset(one_view), target, "opencv4")
    with pytest.raises(InputError, match=r"camera 'cam1': the target was never found"):
        calibrate(sim.obs.subset(sim.obs.camera == 0), target, "opencv4")
    with pytest.raises(InputError, match=r"model must be one of"):
        calibrate(sim.obs, target, "fisheye")
