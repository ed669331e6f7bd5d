"""Geometry is exact: spot centres, ray casting, truth points on the surface."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from scanrig.sim import primitives
from scanrig.sim.laser import BeamPose, LaserSpec, trace_laser
from scanrig.sim.materials import Material
from scanrig.sim.pixel_rays import pixel_rays
from scanrig.sim.raycast import RayCaster, intersect_reference
from scanrig.sim.render import CameraView
from scanrig.sim.sensor import Sensor

from .conftest import plane_scene, strong_camera

#: Acceptance: intensity-weighted spot centre vs true projection, noise-free, high supersampling.
SPOT_CENTRE_TOL_PX = 0.01
#: Embree picks the triangle in float32; the float64 re-intersection must agree with the
#: reference to float64 round-off at ~1 m (1e-12 m is 1000x the round-off, far below any use).
HIT_TOL_M = 1e-12
#: Bilinear interpolation of the undistortion map between pixel centres errs by h²/8 x its
#: curvature: ~1e-4 px at the extreme corners of the strong lens (k1..k3 terms together);
#: 2e-4 px is still 50x below the spot tolerance.
RAY_TABLE_TOL_PX = 2e-4


def _centroid(window) -> np.ndarray:
    e = window.electrons.astype(np.float64)
    v, u = np.mgrid[0:e.shape[0], 0:e.shape[1]]
    return np.array([(u * e).sum() / e.sum() + window.u0, (v * e).sum() / e.sum() + window.v0])


def test_spot_centre_matches_true_projection_with_strong_distortion():
    cam = strong_camera()
    # a wide-ish beam (1 mm waist) keeps pixel-locking of the centroid (a property of sampling,
    # not of the renderer) far below the tolerance; the sensor integrates 12 x 12 samples per pixel.
    scene = plane_scene(sensor=Sensor(supersampling=12, psf_sigma_px=0.7))
    spec = LaserSpec(head_m=(0.15, -0.4, 0.6), waist_m=1e-3, focus_m=0.8)
    view = CameraView(cam, scene)
    # aim at pixels from the centre to near the corners, where the distortion is largest
    targets_px = np.array([[640, 512], [90, 80], [1190, 90], [100, 950], [1180, 940]], float)
    origin, dirs = pixel_rays(cam, targets_px)
    on_plane = origin - (origin[2] / dirs[:, 2])[:, None] * dirs
    errors = []
    for p in on_plane:
        d = p - np.asarray(spec.head_m)
        trace = trace_laser(BeamPose(np.asarray(spec.head_m), d / np.linalg.norm(d)), spec, scene)
        (truth,) = trace.truth_points
        window = view.laser_window(trace)
        errors.append(_centroid(window) - cam.project(truth[None])[0])
    errors = np.array(errors)
    print("spot centre errors (px):", errors.tolist())
    assert np.abs(errors).max() < SPOT_CENTRE_TOL_PX, errors


def test_embree_hits_match_numpy_reference():
    rng = np.random.default_rng(7)
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.1)   # small: the reference is O(rays x faces)
    caster = RayCaster([mesh.smooth_shaded])
    origins = rng.normal(size=(300, 3)) * 0.02 + [0.0, 0.0, -0.5]
    targets = rng.normal(size=(300, 3)) * 0.06
    dirs = targets - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = caster.cast(origins, dirs)
    t_ref = intersect_reference(caster.triangles, origins, dirs)
    assert np.array_equal(np.isfinite(hits.t), np.isfinite(t_ref))
    assert np.abs(hits.t[hits.hit] - t_ref[hits.hit]).max() < HIT_TOL_M


@settings(max_examples=30, deadline=None)
@given(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-60, 60), st.floats(-60, 60))
@example(0.25, -0.296875, 45.0, 60.0)  # off a 2 m plane's edge
@example(-0.3, 0.3, 60.0, 60.0)  # a 2 m plane there lies above a ray starting at 1.5 m
def test_hit_points_lie_on_the_plane(x, y, tilt_x, tilt_y):
    from scanrig.sim.scene import place

    # Tilted 60° about both axes the plane rises to z = 1.66 m and its hit points lie up to 1.6 m
    # from its centre within the drawn x, y: rays start above it, and the plane is 4 m wide.
    mesh = place(primitives.plane((4.0, 4.0)), (0.0, 0.0, 0.1), (tilt_x, tilt_y, 0.0))
    caster = RayCaster([mesh])
    origin = np.array([[x, y, 3.0]])
    hits = caster.cast(origin, np.array([[0.0, 0.0, -1.0]]))
    n = mesh.face_normals[0]
    assert hits.hit[0]
    assert abs((hits.point[0] - mesh.vertices[0]) @ n) < HIT_TOL_M
    assert hits.normal[0] @ [0.0, 0.0, -1.0] < 0          # normal faces the incoming ray


def test_occluded_spot_is_not_rendered():
    """A box between camera and spot hides the spot completely (exact occlusion by ray casting)."""
    from scanrig.sim.scene import SceneObject, place

    cam = strong_camera()
    blocker = SceneObject("blocker", place(primitives.box((0.1, 0.02, 0.1)), (0.0, -0.15, 0.12)),
                          Material("grey", "matte"))
    scene = plane_scene(extra=(blocker,))
    spec = scene.laser
    origin, dirs = pixel_rays(cam, np.array([[640.0, 512.0]]))
    hidden = origin - (origin[2] / dirs[0, 2]) * dirs[0]
    d = hidden - np.asarray(spec.head_m)
    trace = trace_laser(BeamPose(np.asarray(spec.head_m), d / np.linalg.norm(d)), spec, scene)
    assert trace.truth_kind == ["primary"]
    window = CameraView(cam, scene).laser_window(trace)
    assert window is None or window.electrons.max() == 0.0


@pytest.mark.parametrize("model_dist", [(0.0, 0.0, 0.0, 0.0, 0.0), (-0.35, 0.12, 1e-3, -8e-4, -0.01)])
def test_pixel_rays_reproject(model_dist):
    cam = strong_camera()
    cam = cam.with_params(np.r_[cam.params[:4], model_dist])
    rng = np.random.default_rng(3)
    q = rng.uniform([0, 0], [1279, 1023], size=(2000, 2))
    origin, dirs = pixel_rays(cam, q)
    assert np.abs(cam.project(origin + 0.7 * dirs) - q).max() < 1e-8


def test_ray_table_interpolation_reprojects_onto_its_pixels():
    """Sub-pixel rays interpolated between pixel centres reproject onto their pixels."""
    from scanrig.sim.pixel_rays import PixelRayTable

    cam = strong_camera()
    table = PixelRayTable(cam)
    rng = np.random.default_rng(5)
    q = rng.uniform([-0.5, -0.5], [1279.5, 1023.5], size=(5000, 2))
    origin, dirs = table.rays(q)
    assert np.abs(cam.project(origin + 0.7 * dirs) - q).max() < RAY_TABLE_TOL_PX
