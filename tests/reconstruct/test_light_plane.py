"""Light planes: robust fit, ray–plane intersection and its covariance, calibration, classic mode."""

import numpy as np
import pytest

from scanrig.errors import EstimationError, FileFormatError, InputError
from scanrig.geometry import Rig
from scanrig.io.rig_file import save_rig
from scanrig.laser.traces import write_traces
from scanrig.reconstruct.flags import Flag
from scanrig.reconstruct.light_plane import (
    fit_plane,
    fit_plane_robust,
    intersect_stripe_pixels,
    load_light_plane,
    save_light_plane,
)
from scanrig.reconstruct.light_plane_fit import calibrate_light_plane
from scanrig.reconstruct.pipeline import reconstruct_session
from scanrig.reconstruct.points import read_points
from tests.reconstruct.synth import height_field, ring_rig, stripe_traces

#: Monte-Carlo: 3000 draws estimate a standard deviation to 1.3 % (1 σ); 8 % is six of those.
MC_RTOL = 0.08


def _plane_points(rng, n, normal, offset, noise):
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    basis = np.linalg.svd(normal[None])[2][1:]
    p = rng.uniform(-0.2, 0.2, (n, 2)) @ basis + offset * normal
    return p + rng.normal(0.0, noise, (n, 1)) * normal, normal


def test_robust_fit_ignores_outliers():
    rng = np.random.default_rng(71)
    p, normal = _plane_points(rng, 400, [1.0, 0.2, 0.1], 0.05, 1e-4)
    p[:150] += rng.normal(0.0, 0.01, (150, 3))  # 37 % gross outliers
    plane, inliers = fit_plane_robust(p, np.full(400, 1e-4), rng)
    assert abs(abs(plane.normal @ normal) - 1.0) < 1e-6
    assert abs(plane.distance(np.zeros((1, 3)))[0] + np.sign(plane.normal @ normal) * 0.05) < 1e-4
    assert inliers[150:].mean() > 0.98
    # a displaced point is accepted only if its displacement left it within the 3-sigma gate
    true_distance = np.abs(p[:150] @ normal - 0.05)
    assert np.all(true_distance[inliers[:150]] < 3.5e-4)


def test_plane_offset_sigma_matches_monte_carlo():
    rng = np.random.default_rng(72)
    x = np.array([[0.3, 0.1, 0.0]])
    fits = []
    for _ in range(3000):
        p, _ = _plane_points(rng, 30, [0.0, 0.0, 1.0], 0.0, 1e-3)
        fits.append(fit_plane(p))
    spread = np.std([f.distance(x)[0] * np.sign(f.normal[2]) for f in fits])
    predicted = np.sqrt(np.mean([f.offset_sigma(x)[0] ** 2 for f in fits]))
    assert predicted == pytest.approx(spread, rel=MC_RTOL)


def test_ray_plane_covariance_matches_monte_carlo():
    rng = np.random.default_rng(73)
    cam = ring_rig().cameras[0]
    p, _ = _plane_points(rng, 200, [1.0, 0.0, 0.0], 0.0, 0.0)
    plane = fit_plane(p)
    q0 = cam.project(np.array([[0.0, 0.05, 0.02]]))
    sigma_px = 0.5
    q = q0 + rng.normal(0.0, sigma_px, (3000, 2))
    cov_px = np.broadcast_to(np.eye(2) * sigma_px**2, (3000, 2, 2))
    pts, cov = intersect_stripe_pixels(cam, q, cov_px, plane)
    np.testing.assert_allclose(np.cov(pts.T), cov.mean(axis=0), rtol=MC_RTOL, atol=1e-12)


def test_calibrate_light_plane_from_target_poses():
    """A fixed laser plane seen on a target plane at three poses."""
    rng = np.random.default_rng(74)
    cam = ring_rig().cameras[1]
    laser_normal = np.array([1.0, 0.1, 0.05]) / np.linalg.norm([1.0, 0.1, 0.05])
    targets, pixels = [], []
    for tilt, height in ((0.0, 0.0), (0.3, 0.03), (-0.25, 0.06)):
        t_normal = np.array([0.0, np.sin(tilt), np.cos(tilt)])
        # points on both planes: the line where the laser meets the target
        direction = np.cross(laser_normal, t_normal)
        A = np.stack([laser_normal, t_normal, direction])
        origin = np.linalg.solve(A, [0.02, height, 0.0])
        line = origin + np.linspace(-0.1, 0.1, 200)[:, None] * direction
        q = cam.project(line) + rng.normal(0.0, 0.2, (200, 2))
        targets.append((t_normal, height))
        pixels.append(q)
    plane = calibrate_light_plane(cam, targets, pixels, rng).plane
    assert abs(abs(plane.normal @ laser_normal) - 1.0) < 1e-5
    assert abs(abs(plane.offset) - 0.02) < 2e-4
    with pytest.raises(InputError, match="a light plane needs the stripe on the target at 2 or more poses, got 1"):
        calibrate_light_plane(cam, targets[:1], pixels[:1], rng)
    with pytest.raises(InputError, match="target_planes and stripe_pixels must have the same length, got 3 and 2"):
        calibrate_light_plane(cam, targets, pixels[:2], rng)
    with pytest.raises(EstimationError, match="collinear"):
        fit_plane(np.c_[np.arange(5.0), np.zeros(5), np.zeros(5)])


def test_classic_single_camera_mode(tmp_path):
    """One camera and a calibrated plane x = 0.05: the stripe's points on the surface."""
    rng = np.random.default_rng(75)
    rig3 = ring_rig(height_m=0.6)
    cam = rig3.cameras[0]
    save_rig(Rig([cam]), tmp_path / "rig.toml")
    table = stripe_traces(Rig([cam]), [0.05], rng, 0.2)
    write_traces(tmp_path / "traces.parquet", table, {})
    p, _ = _plane_points(rng, 100, [1.0, 0.0, 0.0], 0.05, 0.0)
    save_light_plane(tmp_path / "light_plane.toml", fit_plane(p), cam.name)
    plane, name = load_light_plane(tmp_path / "light_plane.toml")
    assert name == cam.name and abs(plane.offset * np.sign(plane.normal[0]) - 0.05) < 1e-12
    summary = reconstruct_session(tmp_path, light_plane_path=tmp_path / "light_plane.toml")
    cloud, _ = read_points(tmp_path / "points.ply")
    assert summary["points"] == len(cloud) == table.num_rows
    dz = cloud.p_world[:, 2] - height_field(cloud.p_world[:, 0], cloud.p_world[:, 1])
    assert np.sqrt(np.mean(dz**2)) < 2e-4  # one camera, 0.2 px: ~0.1 mm
    assert np.all(cloud.flags & Flag.CALIBRATED_PLANE) and np.all(cloud.n_views == 1)


def test_classic_mode_leaves_out_detections_isolated_from_any_stripe(tmp_path):
    """A line the laser does not cross still has a brightest candidate: three such, each alone on
    its line, are left out and counted; the stripe's points all stay."""
    import pyarrow as pa

    rng = np.random.default_rng(76)
    cam = ring_rig(height_m=0.6).cameras[0]
    save_rig(Rig([cam]), tmp_path / "rig.toml")
    stripe = stripe_traces(Rig([cam]), [0.05], rng, 0.2)
    lines = stripe["line"].to_numpy()
    free = np.setdiff1d(np.arange(lines.max() + 40), lines)[[0, 10, 20]]  # rows the stripe does not reach
    junk = stripe.slice(0, 3)
    junk = junk.set_column(junk.schema.get_field_index("line"), "line", pa.array(free.astype(np.int32)))
    junk = junk.set_column(junk.schema.get_field_index("v"), "v", pa.array(free.astype(float)))
    write_traces(tmp_path / "traces.parquet", pa.concat_tables([stripe, junk]), {})
    p, _ = _plane_points(rng, 100, [1.0, 0.0, 0.0], 0.05, 0.0)
    save_light_plane(tmp_path / "light_plane.toml", fit_plane(p), cam.name)
    summary = reconstruct_session(tmp_path, light_plane_path=tmp_path / "light_plane.toml")
    assert summary["detections_isolated"] == 3
    assert summary["points"] == stripe.num_rows


def test_light_plane_file_errors(tmp_path):
    path = tmp_path / "light_plane.toml"
    path.write_text('format_version = 1\nunits = "m"\ncamera = "cam0"\n')
    with pytest.raises(FileFormatError, match="light_plane.toml"):
        load_light_plane(path)
