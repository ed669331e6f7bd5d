"""inspect_cloud on synthetic parts with known bumps, dents, noise, partial coverage and outliers."""

import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.inspect import AlignmentError, coarse, inspect_cloud
from scanrig.inspect.inspection import MIN_CONSTRAINT

from . import synth

#: Acceptance (issue): alignment error <= 0.01 mm RMS at 40 000 points.
ALIGNMENT_TOL_M = 1e-5
#: Acceptance: deviation error <= 1.5 x the injected noise.
DEVIATION_TOL = 1.5 * synth.NOISE_M
#: Acceptance: bump heights within 0.02 mm.
BUMP_TOL_M = 2e-5
#: Tolerance of the inspections below (the smallest designed bump).
TOLERANCE_M = 1e-4


@pytest.fixture(scope="module")
def mesh():
    return synth.bracket_mesh()


def _check_accuracy(scan, result):
    assert synth.alignment_error_m(scan, result.cad_from_cloud) <= ALIGNMENT_TOL_M
    assert synth.deviation_error_m(scan, result.deviation_m) <= DEVIATION_TOL
    np.testing.assert_array_less(np.abs(synth.bump_height_errors_m(scan, result.deviation_m)), BUMP_TOL_M)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_acceptance_on_a_partial_scan_with_outliers(mesh, seed):
    # 40 000 points seen from one side, 10 % outliers, moved by up to 30 deg and 50 mm
    scan = synth.scan_of(mesh, np.random.default_rng(seed), 40_000)
    result = inspect_cloud(scan.points_m, mesh, tolerance_m=TOLERANCE_M, seed=seed)
    _check_accuracy(scan, result)
    assert result.signed and result.warnings == ()
    assert result.alignment.constraint > MIN_CONSTRAINT
    assert result.stats.n_points == 40_000
    # the 0.5 mm bump and the 0.3 mm dent are found as regions at their places (within 1 mm), with their signs
    centroids = np.array([r.centroid_m for r in result.regions])
    for centre_mm, height_mm, _ in synth.BUMPS_MM[:2]:
        nearest = np.argmin(np.linalg.norm(centroids - np.array(centre_mm) * 1e-3, axis=1))
        assert np.linalg.norm(centroids[nearest] - np.array(centre_mm) * 1e-3) < 1e-3
        assert np.sign(result.regions[nearest].mean_m) == np.sign(height_mm)
        assert result.regions[nearest].facing == "+z"             # both lie on the top face


@pytest.mark.slow
def test_any_starting_pose_is_found(mesh):
    # a full turn of freedom: the coarse alignment needs no hand placing
    scan = synth.scan_of(mesh, np.random.default_rng(7), 20_000, max_angle_deg=180.0)
    result = inspect_cloud(scan.points_m, mesh, tolerance_m=TOLERANCE_M, seed=7)
    assert synth.alignment_error_m(scan, result.cad_from_cloud) <= ALIGNMENT_TOL_M


@pytest.mark.slow
@pytest.mark.parametrize("seed, n_points, outlier_fraction", [(3, 20_000, 0.3), (1, 40_000, 0.1)])
def test_multistart_fallback_without_open3d(mesh, monkeypatch, seed, n_points, outlier_fraction):
    """Without the open3d extra (as installed by ``.[all]``); seed 1 is the acceptance's, on which
    40 random starts missed the pose by 43 mm."""
    monkeypatch.setattr(coarse, "_open3d", lambda: None)
    scan = synth.scan_of(mesh, np.random.default_rng(seed), n_points, outlier_fraction=outlier_fraction)
    result = inspect_cloud(scan.points_m, mesh, tolerance_m=TOLERANCE_M, seed=seed)
    assert result.alignment.method == "multistart + robust ICP"
    assert synth.alignment_error_m(scan, result.cad_from_cloud) <= ALIGNMENT_TOL_M


def test_initial_transform_replaces_the_coarse_search(mesh):
    scan = synth.scan_of(mesh, np.random.default_rng(4), 20_000)
    nudge = synth.random_motion(np.random.default_rng(5), max_angle_deg=2.0, max_shift_m=0.002)
    result = inspect_cloud(scan.points_m, mesh, tolerance_m=TOLERANCE_M,
                           initial_cad_from_cloud=nudge @ scan.cad_from_cloud)
    assert result.alignment.method == "initial + robust ICP"
    _check_accuracy(scan, result)


def test_a_single_face_leaves_the_fit_free_and_says_so(mesh):
    # the top face only: sliding in its plane and turning about its normal change nothing
    rng = np.random.default_rng(12)
    top = np.column_stack([rng.uniform(0.002, 0.018, 4000), rng.uniform(0.002, 0.018, 4000),
                           0.02 + rng.normal(scale=synth.NOISE_M, size=4000)])
    result = inspect_cloud(top, mesh, tolerance_m=TOLERANCE_M, initial_cad_from_cloud=np.eye(4))
    assert result.alignment.constraint < MIN_CONSTRAINT
    assert result.warnings == (("the scanned surface leaves a motion free (e.g. a single plane, or a surface of "
                                "revolution): cad_from_cloud is not determined along it; the deviations are"),)
    assert synth.NOISE_M / 2 < result.stats.rms_m < 2 * synth.NOISE_M      # still the noise, whatever the slide


def test_no_align_measures_in_the_given_frame(mesh):
    scan = synth.scan_of(mesh, np.random.default_rng(6), 5000, partial=False, max_angle_deg=0.0, max_shift_m=0.0)
    result = inspect_cloud(scan.points_m, mesh, tolerance_m=TOLERANCE_M, align=False)
    np.testing.assert_array_equal(result.cad_from_cloud, np.eye(4))
    assert result.alignment.method == "none"
    assert synth.deviation_error_m(scan, result.deviation_m) <= DEVIATION_TOL


def test_sign_is_positive_outside_even_for_a_mesh_wound_inside_out():
    import trimesh

    half_m, margin_m = 0.02, 1.5e-3
    box = trimesh.creation.box(extents=[2 * half_m] * 3)
    rng = np.random.default_rng(8)
    points, face = box.sample(4000, return_index=True, seed=rng)
    # away from the edges, a point moved by up to 1 mm along its face normal stays nearest that face
    away = np.sum(np.abs(points) < half_m - margin_m, axis=1) == 2
    offset_m = rng.uniform(-1e-3, 1e-3, int(away.sum()))
    p = points[away] + offset_m[:, None] * box.face_normals[face[away]]
    flipped = box.copy()
    flipped.invert()
    for cad in (box, flipped):
        result = inspect_cloud(p, cad, tolerance_m=TOLERANCE_M, align=False)
        np.testing.assert_allclose(result.deviation_m, offset_m, atol=1e-12)   # exact up to round-off


def test_open_cad_gives_unsigned_distances_with_a_warning(mesh):
    scan = synth.scan_of(mesh, np.random.default_rng(9), 3000, outlier_fraction=0.0, max_angle_deg=0.0, max_shift_m=0.0)
    open_mesh = mesh.copy()
    open_mesh.update_faces(np.arange(len(mesh.faces)) != 0)
    result = inspect_cloud(scan.points_m, open_mesh, tolerance_m=TOLERANCE_M, align=False)
    assert not result.signed and np.all(result.deviation_m >= 0)
    assert result.warnings == (("the CAD mesh is not closed (not watertight or inconsistently wound): deviations "
                                "are unsigned distances"),)


def test_bad_input_is_refused_with_one_clear_message(mesh):
    with pytest.raises(InputError, match=r"^points_m: the cloud is empty$"):
        inspect_cloud(np.zeros((0, 3)), mesh, tolerance_m=TOLERANCE_M)
    with pytest.raises(InputError, match=r"^tolerance_m must be > 0, got 0.0$"):
        inspect_cloud(np.zeros((5, 3)), mesh, tolerance_m=0.0)
    scan = synth.scan_of(mesh, np.random.default_rng(10), 2000)
    big = mesh.copy()
    big.apply_scale(1000.0)
    with pytest.raises(InputError, match=r"^cad: the CAD is \d+x the size of the cloud \(.* m vs .* m across\): "
                                         r"it looks like millimetres read as metres; give --cad-units mm$"):
        inspect_cloud(scan.points_m, big, tolerance_m=TOLERANCE_M)
    small = mesh.copy()
    small.apply_scale(1e-3)
    with pytest.raises(InputError, match=r"^cad: the CAD is 1/\d+ of the size of the cloud \(.* m vs .* m across\): "
                                         r"it looks like metres read as millimetres; give --cad-units m$"):
        inspect_cloud(scan.points_m, small, tolerance_m=TOLERANCE_M)


@pytest.mark.slow
def test_a_cloud_of_another_shape_cannot_be_aligned(mesh):
    # a sphere of the part's size: no pose puts half of it on the bracket
    rng = np.random.default_rng(11)
    d = rng.normal(size=(5000, 3))
    sphere = 0.03 * d / np.linalg.norm(d, axis=1, keepdims=True)
    message = (r"^the cloud cannot be aligned to the CAD model: the best fit brings \d+ % of the points within "
               r"0.15 mm of the surface \(need 50 %\); is it a scan of this part\? give an initial transform to help$")
    with pytest.raises(AlignmentError, match=message):
        inspect_cloud(sphere, mesh, tolerance_m=TOLERANCE_M, seed=11)
