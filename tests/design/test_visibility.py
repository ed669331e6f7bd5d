"""Visibility: image bounds, back faces, incidence limit, occlusion; surface elements; mesh checks."""

import math

import numpy as np
import pytest
import trimesh

from scanrig.design.candidates import look_at_pose, make_camera
from scanrig.design.elements import MeshError, check_back_faces, check_mesh, refine_mesh, surface_elements
from scanrig.design.spec import CameraSpec
from scanrig.design.visibility import RayCaster, inside, view

from .scenes import sheet

CAMERA = CameraSpec(focal_lengths_m=(0.008,))


def camera_at(center, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), f=0.008):
    return make_camera("c", CAMERA, f, look_at_pose(center, target, up))


def test_camera_facing_a_box_sees_exactly_the_near_face():
    mesh = refine_mesh(trimesh.creation.box((0.1, 0.1, 0.1)), 3000)
    elements = surface_elements(mesh)
    v = view(camera_at([0.6, 0.0, 0.0], up=(0, 0, 1)), elements, RayCaster(mesh), math.radians(80))
    near_face = elements.normals[:, 0] > 0.99
    np.testing.assert_array_equal(v.seen, near_face)
    assert not v.seen_from_behind.any()
    np.testing.assert_allclose(v.cos_incidence[near_face], 0.6 / np.linalg.norm(
        [0.6, 0, 0] - elements.points[near_face], axis=1) * 1.0 - 0.0, atol=0.1)


def test_incidence_limit_removes_oblique_views():
    mesh = sheet(0.2, 10)
    elements = surface_elements(mesh)
    cam = camera_at([0.0, -0.5, 0.3])                     # about 59 degrees from the sheet's normal
    caster = RayCaster(mesh)
    loose = view(cam, elements, caster, math.radians(85))
    strict = view(cam, elements, caster, math.radians(55))
    incidence = np.degrees(np.arccos(loose.cos_incidence))
    assert loose.seen.all()
    np.testing.assert_array_equal(strict.seen, incidence <= 55)
    assert 0 < strict.seen.sum() < len(elements)


def test_occluder_hides_its_shadow_exactly():
    """A 4 cm plate 5 cm above the sheet, camera straight above: the hidden area is its central projection."""
    floor = sheet(0.3, 60)
    plate = trimesh.creation.box((0.04, 0.04, 0.002))
    plate.apply_translation([0.0, 0.0, 0.05])
    mesh = trimesh.util.concatenate([floor, plate])
    elements = surface_elements(mesh)
    on_floor = np.abs(elements.points[:, 2]) < 1e-12
    height = 0.6
    v = view(camera_at([0.0, 0.0, height], up=(0, 1, 0)), elements, RayCaster(mesh), math.radians(89))
    half_shadow = 0.02 * height / (height - 0.049)       # the plate's lower face is at z = 0.049
    inside = np.all(np.abs(elements.points[:, :2]) < half_shadow - 0.003, axis=1)   # margin: element size 5 mm
    outside = np.any(np.abs(elements.points[:, :2]) > half_shadow + 0.003, axis=1)
    assert not v.seen[on_floor & inside].any()
    assert v.seen[on_floor & outside].all()


def test_points_outside_the_image_are_not_seen():
    mesh = sheet(2.0, 20)                                 # far larger than the field of view
    elements = surface_elements(mesh)
    cam = camera_at([0.0, 0.0, 0.5], up=(0, 1, 0))
    v = view(cam, elements, RayCaster(mesh), math.radians(89))
    q = cam.project(elements.points)
    inside = (q[:, 0] >= -0.5) & (q[:, 0] <= cam.width - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] <= cam.height - 0.5)
    np.testing.assert_array_equal(v.seen, inside)
    assert 0 < inside.sum() < len(elements)


def test_sheet_seen_from_behind_is_reported():
    mesh = sheet(0.2, 10)
    elements = surface_elements(mesh)
    v = view(camera_at([0.1, 0.0, -0.5]), elements, RayCaster(mesh), math.radians(80))
    assert not v.seen.any() and v.seen_from_behind.all()
    with pytest.raises(MeshError, match=r"sheet\.stl: 100\.0 % of the surface .* is seen from behind"):
        check_back_faces(elements, v.seen_from_behind, "sheet.stl")


def test_hole_in_a_box_is_found_where_a_camera_looks_through_it():
    box = refine_mesh(trimesh.creation.box((0.1, 0.1, 0.1)), 3000)
    top = np.flatnonzero((box.face_normals[:, 2] > 0.99) & (np.abs(box.triangles_center[:, :2]).max(axis=1) < 0.03))
    open_box = trimesh.Trimesh(box.vertices, np.delete(box.faces, top, axis=0), process=False)
    check_mesh(open_box, "open.stl")                      # open is fine as such
    elements = surface_elements(open_box)
    caster = RayCaster(open_box)
    from_side = view(camera_at([0.6, 0.0, 0.0]), elements, caster, math.radians(80))
    from_top = view(camera_at([0.0, 0.05, 0.6], up=(0, 1, 0)), elements, caster, math.radians(80))
    assert not from_side.seen_from_behind.any()
    assert from_top.seen_from_behind.any()                # the inside of the bottom face, through the hole
    with pytest.raises(MeshError, match="open there"):
        check_back_faces(elements, from_top.seen_from_behind, "open.stl")


def test_inverted_closed_mesh_is_rejected():
    mesh = trimesh.creation.box((0.1, 0.1, 0.1))
    mesh.invert()
    with pytest.raises(MeshError, match=r"inv\.stl: the normals point inwards \(negative volume\)"):
        check_mesh(mesh, "inv.stl")


def test_empty_mesh_is_rejected():
    with pytest.raises(MeshError, match="e.stl: the mesh has no faces with area"):
        check_mesh(trimesh.Trimesh(np.zeros((3, 3)), [[0, 1, 2]], process=False), "e.stl")


def test_sampled_elements_cover_the_area_evenly():
    mesh = refine_mesh(trimesh.creation.box((0.3, 0.1, 0.1)), 5000)
    n = 4000
    elements = surface_elements(mesh, n, np.random.default_rng(3))
    assert len(elements) == n < len(mesh.faces)
    assert elements.total_area == pytest.approx(mesh.area, rel=1e-12)
    # share of points on the two 0.1 x 0.1 end faces: binomial, 5 standard errors
    ends = np.abs(elements.points[:, 0]) > 0.15 - 1e-12
    share = 2 * 0.01 / mesh.area
    assert ends.mean() == pytest.approx(share, abs=5 * math.sqrt(share * (1 - share) / n))
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[elements.face_index], elements.points)
    assert np.all(bary > -1e-12) and np.allclose(bary.sum(axis=1), 1.0)   # on their own faces


def test_refined_mesh_keeps_the_surface():
    box = trimesh.creation.box((0.2, 0.1, 0.05))
    fine = refine_mesh(box, 5000)
    assert 5000 <= len(fine.faces) <= 10_000
    assert fine.area == pytest.approx(box.area, rel=1e-12)
    assert refine_mesh(fine, 100) is fine


def test_inside_tells_enclosed_points_from_points_behind_a_sheet_or_over_a_hole():
    box = trimesh.creation.box((0.2, 0.2, 0.2))
    caster = RayCaster(box)
    points = np.array([[0.0, 0.0, 0.0], [0.05, -0.09, 0.02], [0.3, 0.0, 0.0], [0.0, 0.0, 0.5]])
    np.testing.assert_array_equal(inside(points, np.zeros(3), caster), [True, True, False, False])
    wall = sheet(0.2, 4)                                   # normals +z: a camera below sees its back
    assert not inside(np.array([[0.0, 0.0, -0.3]]), np.zeros(3), RayCaster(wall))[0]
