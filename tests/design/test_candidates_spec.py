"""Candidate poses, the symmetric ring, and the design TOML with its error messages."""

import numpy as np
import pytest

from scanrig.design.candidates import (MountingError, check_region, look_at_pose, make_camera, mounting_positions,
                                       ring_positions)
from scanrig.design.spec import CameraSpec, DesignSpec, MountingSpec, default_spec, load_spec
from scanrig.errors import FileFormatError, InputError


def test_look_at_pose_puts_the_target_on_the_principal_point_and_up_up():
    rng = np.random.default_rng(1)
    for _ in range(20):
        center, target = rng.normal(size=3), rng.normal(size=3)
        cam = make_camera("c", CameraSpec(), 0.01, look_at_pose(center, target, [0, 0, 1]))
        q = cam.project(np.array([target, target + [0, 0, 0.01]]))
        np.testing.assert_allclose(q[0], [cam.params[2], cam.params[3]], atol=1e-9)
        assert q[1, 1] < q[0, 1]                              # up in the world is up in the image
        np.testing.assert_allclose(cam.center_world, center, atol=1e-12)


def test_look_at_along_up_is_refused():
    with pytest.raises(InputError, match="looks along 'up'"):
        look_at_pose([0, 0, 1], [0, 0, 0], [0, 0, 1])


@pytest.mark.parametrize("shape", ["cylinder", "sphere"])
def test_positions_fill_the_region(shape):
    m = MountingSpec(shape=shape, radius_m=(0.8, 1.2), height_m=(0.1, 0.6), elevation_deg=(10, 50),
                     look_at=(0.1, 0.2, 0.3), n_candidates=200)
    p = mounting_positions(m) - np.array(m.look_at)
    if shape == "cylinder":
        r, h = np.hypot(p[:, 0], p[:, 1]), p[:, 2]
        assert r.min() >= 0.8 - 1e-12 and r.max() <= 1.2 + 1e-12
        assert h.min() >= 0.1 - 1e-12 and h.max() <= 0.6 + 1e-12
    else:
        r = np.linalg.norm(p, axis=1)
        elevation = np.degrees(np.arcsin(p[:, 2] / r))
        assert r.min() >= 0.8 - 1e-12 and r.max() <= 1.2 + 1e-12
        assert elevation.min() >= 10 - 1e-9 and elevation.max() <= 50 + 1e-9
    azimuth = np.arctan2(p[:, 1], p[:, 0])
    counts, _ = np.histogram(azimuth, bins=8, range=(-np.pi, np.pi))
    assert counts.min() >= 0.7 * 200 / 8                      # low-discrepancy: no empty sector
    np.testing.assert_array_equal(mounting_positions(m), mounting_positions(m))   # deterministic


def test_ring_is_symmetric():
    m = MountingSpec(radius_m=(1.0, 2.0), height_m=(0.0, 1.0), look_at=(0.0, 0.0, 0.0))
    p = ring_positions(m, 4)
    np.testing.assert_allclose(np.hypot(p[:, 0], p[:, 1]), 1.5)
    np.testing.assert_allclose(p[:, 2], 0.5)
    np.testing.assert_allclose(p.sum(axis=0), [0, 0, 2.0], atol=1e-12)


def test_region_inside_the_object_is_impossible():
    m = MountingSpec(radius_m=(0.05, 0.1), height_m=(0.0, 0.05), look_at=(0.0, 0.0, 0.0))
    with pytest.raises(MountingError, match=r"\[mounting\] radius_m \[0\.05, 0\.1\]: every allowed position lies "
                                            r"inside the object's bounding sphere \(radius 0\.5 m"):
        check_region(m, np.zeros(3), 0.5)


def test_default_spec_scales_with_the_object():
    spec = default_spec(DesignSpec(), np.array([0.0, 0.0, 0.1]), 0.25)
    assert spec.mounting.radius_m == (0.625, 1.0)
    assert spec.mounting.look_at == (0.0, 0.0, 0.1)
    assert spec.target.sigma_m == pytest.approx(5e-4)
    assert len(spec.camera.focal_lengths_m) == 1


def test_load_spec_reads_every_table(tmp_path):
    (tmp_path / "poses.toml").write_text("")
    path = tmp_path / "d.toml"
    path.write_text("""
[camera]
width_px = 2048
height_px = 1536
pixel_pitch_m = 3.45e-6
focal_lengths_m = [0.012, 0.016]
f_number = 2.8
[mounting]
shape = "sphere"
radius_m = [0.8, 1.2]
elevation_deg = [10.0, 60.0]
look_at = [0.0, 0.0, 0.1]
n_candidates = 30
rig = "poses.toml"
[laser]
mode = "stripe"
sigma_px = 0.2
[target]
sigma_m = 2e-4
[calibration]
rotation_sigma_rad = 1e-4
""")
    spec = load_spec(path)
    assert spec.camera.focal_lengths_m == (0.012, 0.016)
    assert spec.mounting.shape == "sphere" and spec.mounting.n_candidates == 30
    assert spec.mounting.rig == (tmp_path / "poses.toml").resolve()
    assert spec.laser.mode == "stripe" and spec.target.sigma_m == 2e-4
    assert spec.calibration.rotation_sigma_rad == 1e-4


@pytest.mark.parametrize("text, message", [
    ("[camra]\n", r"top level: unknown field 'camra' \(did you mean 'camera'\?\)"),
    ("[camera]\nfocal_length_m = [0.01]\n",
     r"\[camera\]: unknown field 'focal_length_m' \(did you mean 'focal_lengths_m'\?\)"),
    ("[mounting]\nradius_m = [1.2, 0.8]\n",
     r"\[mounting\] radius_m must be \[min, max\] with 0.0 <= min <= max, got \(1.2, 0.8\)"),
    ("[mounting]\nshape = \"cube\"\n", r"\[mounting\] shape must be \"cylinder\" or \"sphere\", got 'cube'"),
    ("[laser]\nsigma_px = -1\n", r"\[laser\] sigma_px must be a positive number, got -1"),
    ("[target]\nmin_views = 1\n", r"\[target\] min_views must be an integer >= 2, got 1"),
    ("[target]\nmax_incidence_deg = 95\n", r"\[target\] max_incidence_deg must be a number in \(0, 90\), got 95"),
    ("[camera]\nwidth_px = 12.5\n", r"\[camera\] width_px must be a positive integer, got 12.5"),
    ("camera = 3\n", r"\[camera\] must be a table"),
])
def test_bad_spec_names_file_and_field(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(FileFormatError, match="bad.toml: " + message):
        load_spec(path)


def test_missing_spec_file():
    with pytest.raises(FileFormatError, match="nowhere.toml: file not found"):
        load_spec("nowhere.toml")
