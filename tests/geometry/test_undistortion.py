"""Blocked Newton undistortion: kernel against the reference formulas, blocks, convergence flags."""

import numpy as np
import pytest

import scanrig.geometry.distortion as distortion
from scanrig.geometry import Camera
from tests.geometry.cameras import MODELS, random_camera

#: Round trip project(unproject(q)) required by the issue, pixels.
ROUND_TRIP_PX = 1e-6
#: The in-place kernel and the reference formulas differ only in the order of floating-point
#: operations: a few ulps of values of order one.
KERNEL_ATOL = 1e-13


def _coefficient_sets(rng):
    """Full 12-vectors exercising each skipped-term branch of the kernel."""
    sets = []
    for model in MODELS:
        for tangential in (True, False):
            d = random_camera(rng, model, k1_max=0.4)._dist_full.copy()
            if not tangential:
                d[2:4] = 0.0
            sets.append(d)
    no_k3 = sets[2].copy()
    no_k3[4] = 0.0  # k3 = 0 takes the shorter polynomial
    return sets + [no_k3]


def test_newton_kernel_matches_the_reference_distortion_and_jacobian():
    rng = np.random.default_rng(31)
    for d in _coefficient_sets(rng):
        x, y = rng.uniform(-0.6, 0.6, (2, 500))
        tx, ty = rng.uniform(-0.6, 0.6, (2, 500))
        work = distortion._NewtonWork(d, 500)
        res2 = work.residual(x, y, tx, ty)
        xd, yd, j00, j01, j10, j11, _, _ = distortion._distort_and_jacobian_xy(x, y, d)
        r0, r1 = xd - tx, yd - ty
        np.testing.assert_allclose(res2, r0**2 + r1**2, rtol=1e-12, atol=1e-24)
        det = j00 * j11 - j01 * j10
        x_ref = x - (j11 * r0 - j01 * r1) / det
        y_ref = y - (j00 * r1 - j10 * r0) / det
        x_new, y_new = x.copy(), y.copy()
        work.step(x_new, y_new)
        np.testing.assert_allclose(x_new, x_ref, rtol=0, atol=KERNEL_ATOL * np.abs(x_ref).max())
        np.testing.assert_allclose(y_new, y_ref, rtol=0, atol=KERNEL_ATOL * np.abs(y_ref).max())


@pytest.mark.parametrize("model", MODELS)
def test_block_size_and_stage_split_do_not_change_the_result(model, monkeypatch):
    rng = np.random.default_rng(32)
    cam = random_camera(rng, model, k1_max=0.6)
    u, v = np.meshgrid(np.linspace(-200, cam.width + 200, 90), np.linspace(-200, cam.height + 200, 70))
    q = np.c_[u.ravel(), v.ravel()]
    q[::97] = np.nan
    xy, ok = cam.unproject(q)
    for block, block_iter in ((37, 4), (1000, 1), (64, 8)):
        monkeypatch.setattr(distortion, "UNDISTORT_BLOCK", block)
        monkeypatch.setattr(distortion, "UNDISTORT_BLOCK_ITER", block_iter)
        xy_b, ok_b = cam.unproject(q)
        np.testing.assert_array_equal(ok_b, ok)
        # Blocks stop when all their points have converged, so a point may take one more step.
        np.testing.assert_allclose(xy_b[ok], xy[ok], rtol=0, atol=1e-12)
        assert np.isnan(xy_b[~ok]).all()


@pytest.mark.parametrize("model", MODELS)
def test_every_pixel_with_a_preimage_inside_the_fold_converges(model):
    """The flag is false only where the model is not invertible.

    Undistorted points on the near side of every fold (positive Jacobian determinant from the
    axis out to the point) are distorted into pixels; each of those pixels must unproject, with
    the flag set, to a point that projects back onto it. Strong distortion over a field out to
    r = 2 (64° off axis in the corners), where plain Newton from the distorted point often lands
    on a root beyond the fold.
    Pixels more than 3 normalised units off axis (near a pole of the rational model) are left
    out: no lens images them.
    """
    rng = np.random.default_rng(33)
    worst = 0.0
    for _ in range(25):
        cam = random_camera(rng, model, k1_max=0.6)
        x, y = np.meshgrid(np.linspace(-1.6, 1.6, 121), np.linspace(-1.3, 1.3, 97))
        xy = np.c_[x.ravel(), y.ravel()]
        inside = distortion.one_to_one_to_axis(xy, cam._dist_full, np.ones(len(xy), bool))
        xy_d = distortion.distort(xy, cam._dist_full)
        inside &= np.hypot(xy_d[:, 0], xy_d[:, 1]) <= 3.0
        q = xy_d[inside] * cam.params[:2] + cam.params[2:4]
        xy_back, ok = cam.unproject(q)
        assert ok.all(), f"{(~ok).sum()} invertible pixels flagged as not converged"
        back = cam.project_cam(np.c_[xy_back, np.ones(len(xy_back))])
        worst = max(worst, np.abs(back - q).max())
    assert worst <= ROUND_TRIP_PX


def test_unproject_of_pixels_and_of_normalised_coordinates_agree():
    cam = Camera("c", "opencv8", [900, 910, 650, 500, -0.3, 0.1, 1e-3, -2e-3, 0.01, 0.02, -0.01, 0.005],
                 1280, 1024)
    rng = np.random.default_rng(34)
    q = rng.uniform([0, 0], [1280, 1024], (3000, 2))
    xy, ok = cam.unproject(q)
    xy2, ok2 = distortion.undistort((q - cam.params[2:4]) / cam.params[:2], cam._dist_full)
    np.testing.assert_array_equal(ok, ok2)
    np.testing.assert_array_equal(xy, xy2)
    origins, dirs = cam.rays(q)
    d_cam = dirs @ cam.cam_from_world.R.T
    np.testing.assert_allclose(d_cam[:, :2] / d_cam[:, 2:], xy, rtol=0, atol=1e-14)
    np.testing.assert_allclose(origins, np.broadcast_to(cam.center_world, origins.shape), rtol=0, atol=0)
