"""N-view triangulation: exactness, optimality, honest covariance, failure codes, bad input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

import scanrig.geometry.triangulation as triangulation_module
from scanrig.errors import InputError, ShapeError
from scanrig.geometry import Camera, Rig, RigidTransform
from scanrig.geometry.triangulation import Reason, intersect_rays, triangulate
from tests.reconstruct.synth import look_at, observe, points_in_cube, ring_rig

#: Noise-free points come back to round-off: the undistortion converges to 1e-12 in normalised
#: units (~1e-12 m at 1 m), so 1e-9 m leaves three orders of margin.
EXACT_TOL_M = 1e-9
#: Pixel noise of the synthetic-truth tests (the brief's 0.3 px).
SIGMA_PX = 0.3
#: Accuracy acceptance: the closed form's RMS error within 2 % of the Gauss–Newton optimum's.
CLOSED_FORM_RMS_RATIO = 1.02
#: Whitened errors have unit spread; with 3 × 6000 samples the standard error of the sample
#: standard deviation is 1/sqrt(2 × 18000) = 0.005, so ±0.05 is ten standard errors plus room for
#: the first-order (linearisation) approximation.
WHITENED_STD_TOL = 0.05


def _rms(e):
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def test_noise_free_points_are_exact():
    rng = np.random.default_rng(11)
    rig = ring_rig((-50.0, -10.0, 30.0, 70.0))
    p_true = points_in_cube(rng, 2000)
    q = observe(rig, p_true, rng, 0.0)
    for refine in (False, True):
        p, info = triangulate(rig, q, refine=refine)
        assert info.ok.all()
        assert np.abs(p - p_true).max() < EXACT_TOL_M
        assert np.all(info.n_views == 4)


def test_gauss_newton_reaches_the_reprojection_optimum():
    """The refined point equals scipy's least-squares minimiser of the weighted reprojection error."""
    rng = np.random.default_rng(12)
    rig = ring_rig()
    p_true = points_in_cube(rng, 30)
    sigma = rng.uniform(0.1, 0.6, (3, 30))
    q = np.stack([cam.project(p_true) for cam in rig.cameras]) + rng.normal(0.0, 1.0, (3, 30, 2)) * sigma[..., None]
    p, info = triangulate(rig, q, sigma_px=sigma)
    for k in range(30):
        def residual(x, k=k):
            return np.concatenate([(cam.project(x[None])[0] - q[i, k]) / sigma[i, k]
                                   for i, cam in enumerate(rig.cameras)])
        ref = least_squares(residual, p_true[k], xtol=1e-15, ftol=1e-15, gtol=1e-15).x
        # 1e-3 of the point's sigma: far below the noise, far above the solvers' round-off.
        assert np.linalg.norm(p[k] - ref) < 1e-3 * info.sigma[k]
        assert info.chi2[k] == pytest.approx(np.sum(residual(ref) ** 2), rel=1e-6)


def test_closed_form_is_within_two_percent_of_the_optimum():
    rng = np.random.default_rng(13)
    rig = ring_rig()
    p_true = points_in_cube(rng, 20000)
    q = observe(rig, p_true, rng, SIGMA_PX)
    p_fast, _ = triangulate(rig, q, sigma_px=SIGMA_PX, refine=False)
    p_opt, _ = triangulate(rig, q, sigma_px=SIGMA_PX, refine=True)
    assert _rms(p_fast - p_true) <= CLOSED_FORM_RMS_RATIO * _rms(p_opt - p_true)


@pytest.mark.parametrize("refine", [True, False])
def test_covariance_predicts_the_error_spread(refine):
    rng = np.random.default_rng(14)
    rig = ring_rig()
    p_true = points_in_cube(rng, 6000)
    q = observe(rig, p_true, rng, SIGMA_PX)
    p, info = triangulate(rig, q, sigma_px=SIGMA_PX, refine=refine)
    L = np.linalg.cholesky(info.cov)
    z = np.linalg.solve(L, (p - p_true)[..., None])[..., 0]
    assert abs(z.std() - 1.0) < WHITENED_STD_TOL
    # sigma is the largest axis: no single-axis error spread can exceed it on average.
    assert np.mean(np.linalg.norm(p - p_true, axis=1) ** 2) <= 3 * np.mean(info.sigma**2)


def test_anisotropic_pixel_covariance_is_used():
    """Large noise along v in one camera: the full covariance beats its isotropic summary."""
    rng = np.random.default_rng(15)
    rig = ring_rig()
    p_true = points_in_cube(rng, 4000)
    q = np.stack([cam.project(p_true) for cam in rig.cameras])
    cov = np.zeros((3, 4000, 2, 2))
    cov[..., 0, 0] = 0.05**2
    cov[..., 1, 1] = 0.05**2
    cov[1, :, 1, 1] = 2.0**2
    q[1, :, 1] += rng.normal(0.0, 2.0, 4000)
    q += rng.normal(0.0, 0.05, q.shape)
    p_full, info = triangulate(rig, q, cov_px=cov)
    iso = np.sqrt(0.5 * (cov[..., 0, 0] + cov[..., 1, 1]))
    p_iso, _ = triangulate(rig, q, sigma_px=iso)
    assert _rms(p_full - p_true) < _rms(p_iso - p_true)
    predicted_rms = np.sqrt(np.mean(np.trace(info.cov, axis1=1, axis2=2)))
    assert _rms(p_full - p_true) == pytest.approx(predicted_rms, rel=WHITENED_STD_TOL)
    z = np.linalg.solve(np.linalg.cholesky(info.cov), (p_full - p_true)[..., None])[..., 0]
    assert abs(z.std() - 1.0) < 2 * WHITENED_STD_TOL


def test_isotropic_cov_px_equals_sigma_px():
    rng = np.random.default_rng(16)
    rig = ring_rig()
    q = observe(rig, points_in_cube(rng, 50), rng, SIGMA_PX)
    cov = np.zeros((3, 50, 2, 2))
    cov[..., 0, 0] = cov[..., 1, 1] = SIGMA_PX**2
    p_a, info_a = triangulate(rig, q, sigma_px=SIGMA_PX)
    p_b, info_b = triangulate(rig, q, cov_px=cov)
    np.testing.assert_allclose(p_a, p_b, rtol=0, atol=EXACT_TOL_M)
    np.testing.assert_allclose(info_a.cov, info_b.cov, rtol=1e-9)


def test_missing_views_are_skipped_and_counted():
    rng = np.random.default_rng(17)
    rig = ring_rig((-50.0, -10.0, 30.0, 70.0))
    p_true = points_in_cube(rng, 400)
    q = observe(rig, p_true, rng, 0.0)
    drop = rng.integers(0, 4, 400)
    q[drop, np.arange(400)] = np.nan
    q[:, :10] = np.nan
    q[0, :10] = 100.0  # one view only
    p, info = triangulate(rig, q)
    assert np.all(info.reason[:10] == Reason.FEW_VIEWS) and np.isnan(p[:10]).all()
    assert np.all(info.n_views[10:] == 3)
    assert not info.used[drop[10:], np.arange(10, 400)].any()
    assert np.abs(p[10:] - p_true[10:]).max() < EXACT_TOL_M


def test_parallel_rays_fail():
    """Two cameras 1 mm apart looking at a point 1 m away: 0.06° between the rays."""
    cam_a = Camera("a", "pinhole", [1000, 1000, 320, 240], 640, 480, look_at(np.array([0.0, -1.0, 0.0])))
    cam_b = cam_a.with_pose(look_at(np.array([0.001, -1.0, 0.0])))
    cam_b = Camera("b", "pinhole", cam_b.params, 640, 480, cam_b.cam_from_world)
    p_true = np.array([[0.0, 0.0, 0.0]])
    q = np.stack([cam_a.project(p_true), cam_b.project(p_true)])
    p, info = triangulate([cam_a, cam_b], q)
    assert info.reason[0] == Reason.PARALLEL and np.isnan(p).all()
    assert info.max_angle_rad[0] < np.deg2rad(0.1)
    p, info = triangulate([cam_a, cam_b], q, min_angle_rad=0.0)
    assert info.ok[0] and np.abs(p - p_true).max() < 1e-6


def test_point_behind_the_cameras_fails():
    """Two cameras side by side looking along +y whose rays diverge: they meet behind both."""
    pose_a = RigidTransform(np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), np.zeros(3))
    cam_a = Camera("a", "pinhole", [1000, 1000, 320, 240], 640, 480, pose_a)
    cam_b = Camera("b", "pinhole", [1000, 1000, 320, 240], 640, 480,
                   RigidTransform(pose_a.R, -pose_a.R @ np.array([0.1, 0.0, 0.0])))
    # a looks left (u < cx), b looks right: the lines cross at y < 0, behind the image planes.
    q = np.array([[[220.0, 240.0]], [[420.0, 240.0]]])
    p, info = triangulate([cam_a, cam_b], q)
    assert info.reason[0] == Reason.BEHIND and np.isnan(p).all()


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), order=st.permutations(range(4)))
def test_camera_order_does_not_matter(seed, order):
    rng = np.random.default_rng(seed)
    rig = ring_rig((-50.0, -10.0, 30.0, 70.0))
    q = observe(rig, points_in_cube(rng, 20), rng, 0.5)
    p, info = triangulate(rig, q, sigma_px=0.5)
    perm = Rig([rig.cameras[i] for i in order])
    p_perm, info_perm = triangulate(perm, q[list(order)], sigma_px=0.5)
    np.testing.assert_allclose(p_perm, p, rtol=0, atol=EXACT_TOL_M)
    np.testing.assert_allclose(info_perm.chi2, info.chi2, rtol=1e-6)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_moving_the_world_moves_the_points(seed):
    """Triangulation commutes with a rigid change of world frame (cameras and points together)."""
    rng = np.random.default_rng(seed)
    rig = ring_rig()
    q = observe(rig, points_in_cube(rng, 20), rng, 0.5)
    new_from_world = RigidTransform.from_rvec_tvec(rng.normal(0, 1, 3), rng.normal(0, 1, 3))
    moved = Rig([c.with_pose(c.cam_from_world @ new_from_world.inverse()) for c in rig.cameras])
    p, _ = triangulate(rig, q, sigma_px=0.5)
    p_new, _ = triangulate(moved, q, sigma_px=0.5)
    np.testing.assert_allclose(p_new, new_from_world.apply(p), rtol=0, atol=EXACT_TOL_M)


def test_blocks_give_the_same_result_as_one_block(monkeypatch):
    rng = np.random.default_rng(18)
    rig = ring_rig()
    q = observe(rig, points_in_cube(rng, 1000), rng, SIGMA_PX)
    p, info = triangulate(rig, q, sigma_px=SIGMA_PX)
    monkeypatch.setattr(triangulation_module, "CHUNK_POINTS", 77)
    p_blocks, info_blocks = triangulate(rig, q, sigma_px=SIGMA_PX)
    np.testing.assert_array_equal(p_blocks, p)
    np.testing.assert_array_equal(info_blocks.used, info.used)


def test_empty_input():
    p, info = triangulate(ring_rig(), np.zeros((3, 0, 2)))
    assert p.shape == (0, 3) and info.cov.shape == (0, 3, 3) and info.used.shape == (3, 0)


def test_intersect_rays_two_lines():
    centers = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    dirs = np.array([[[0.0, 1.0, 0.0]], [[-1.0, 1.0, 0.0]]])
    dirs /= np.linalg.norm(dirs, axis=2, keepdims=True)
    p, A_inv, singular = intersect_rays(centers, dirs, np.ones((2, 1)))
    np.testing.assert_allclose(p, [[0.0, 1.0, 0.0]], atol=1e-15)
    assert not singular[0]


def test_bad_shapes_are_named():
    rig = ring_rig()
    with pytest.raises(ShapeError, match=r"q_obs must have shape \(3, N, 2\) for 3 cameras, got \(2, 5, 2\)"):
        triangulate(rig, np.zeros((2, 5, 2)))
    with pytest.raises(ShapeError, match=r"sigma_px must be a scalar or have shape \(3, 5\), got \(5,\)"):
        triangulate(rig, np.zeros((3, 5, 2)), sigma_px=np.ones(5))
    with pytest.raises(ShapeError, match=r"cov_px must have shape \(3, 5, 2, 2\), got \(3, 5, 2\)"):
        triangulate(rig, np.zeros((3, 5, 2)), cov_px=np.ones((3, 5, 2)))
    with pytest.raises(ShapeError, match=r"dirs must have shape \(3, 5, 3\), got \(3, 5, 2\)"):
        triangulate(rig, np.zeros((3, 5, 2)), dirs=np.ones((3, 5, 2)))
    with pytest.raises(InputError, match="rig must be a Rig or a non-empty sequence of Camera objects"):
        triangulate([], np.zeros((0, 5, 2)))


def _reference_closed_form(rig, q, sigma, min_angle_rad):
    """The weighted closed form written plainly with (N, 3, 3) stacks and LAPACK, for comparison."""
    cams = rig.cameras
    n = q.shape[1]
    dirs = np.stack([cam.rays(qi)[1] for cam, qi in zip(cams, q)])
    used = np.isfinite(dirs).all(axis=2) & np.isfinite(sigma) & (sigma > 0)
    dirs = np.where(used[..., None], dirs, 0.0)
    centers = np.array([cam.center_world for cam in cams])
    focal = np.array([np.sqrt(cam.params[0] * cam.params[1]) for cam in cams])

    def solve(w):
        P = np.eye(3) - np.einsum("cni,cnj->cnij", dirs, dirs)  # (I - d dT) per view
        A = np.einsum("cn,cnij->nij", w, P)
        b = np.einsum("cn,cnij,cj->ni", w, P, centers)
        ok = np.abs(np.linalg.det(A)) > 1e-12 * np.abs(np.trace(A, axis1=1, axis2=2) / 3) ** 3
        A_inv = np.full_like(A, np.nan)
        A_inv[ok] = np.linalg.inv(A[ok])
        return np.einsum("nij,nj->ni", A_inv, b), A_inv

    p0, _ = solve(used.astype(float))
    t = np.einsum("cni,cni->cn", p0[None] - centers[:, None], dirs)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = (focal[:, None] / (sigma * t)) ** 2
    w = np.where(used & np.isfinite(w), w, 0.0)
    p, cov = solve(w)
    angles = []
    for i in range(len(cams)):
        for j in range(i + 1, len(cams)):
            c = np.where(used[i] & used[j], np.einsum("ni,ni->n", dirs[i], dirs[j]), np.nan)
            angles.append(np.arccos(np.clip(c, -1.0, 1.0)))
    min_angle, max_angle = np.fmin.reduce(angles, axis=0), np.fmax.reduce(angles, axis=0)  # skip NaNs
    q_hat = np.stack([cam.project(p) for cam in cams])
    r2 = np.where(used, np.sum((q - q_hat) ** 2, axis=2), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        chi2 = np.sum(np.where(used, r2 / sigma**2, 0.0), axis=0)
        residual_px = np.sqrt(r2.sum(axis=0) / used.sum(axis=0))
    good = (used.sum(axis=0) >= 2) & np.isfinite(p).all(axis=1) & (max_angle >= min_angle_rad)
    return p, cov, good, chi2, residual_px, min_angle, max_angle


@pytest.mark.parametrize("model", ["pinhole", "opencv5"])
def test_closed_form_equals_the_plain_normal_equations(model):
    """The component arithmetic of the closed form equals the textbook formulas, field by field."""
    rng = np.random.default_rng(19)
    rig = ring_rig((-50.0, -10.0, 30.0, 70.0), model=model)
    n = 3000
    q = observe(rig, points_in_cube(rng, n), rng, SIGMA_PX)
    q[rng.integers(0, 4, n), np.arange(n)] = np.nan  # a missing view each
    q[:, :20] = np.nan
    q[1, :20] = 300.0  # one view only
    sigma = rng.uniform(0.1, 0.6, (4, n))
    sigma[2, 20:40] = 0.0  # unusable detections
    p, info = triangulate(rig, q, sigma_px=sigma, refine=False)
    p_ref, cov_ref, good, chi2, residual_px, min_angle, max_angle = _reference_closed_form(
        rig, q, sigma, triangulation_module.MIN_TRIANGULATION_ANGLE_RAD)
    np.testing.assert_array_equal(info.ok, good)
    assert good.sum() > 0.9 * n
    np.testing.assert_allclose(p[good], p_ref[good], rtol=0, atol=1e-12)
    scale = np.abs(cov_ref[good]).max(axis=(1, 2))[:, None, None]
    np.testing.assert_allclose(info.cov[good] / scale, cov_ref[good] / scale, rtol=0, atol=1e-9)
    sigma_ref = np.sqrt(np.linalg.eigvalsh(cov_ref[good])[:, -1])
    np.testing.assert_allclose(info.sigma[good], sigma_ref, rtol=1e-9)
    np.testing.assert_allclose(info.chi2[good], chi2[good], rtol=1e-9)
    np.testing.assert_allclose(info.residual_px[good], residual_px[good], rtol=1e-9)
    np.testing.assert_allclose(info.min_angle_rad, min_angle, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(info.max_angle_rad, max_angle, rtol=1e-12, equal_nan=True)
    assert np.isnan(p[~good]).all() and np.isnan(info.cov[~good]).all() and np.isnan(info.sigma[~good]).all()
