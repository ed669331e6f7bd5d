"""Edge pixels on one flat, matte, evenly lit plane: sub-pixel rays met in closed form."""

from __future__ import annotations

from unittest import mock

import numpy as np
import pytest

import scanrig.sim.render as render
from scanrig.sim import default_rig, load_scene
from scanrig.sim.calibration_shots import calibration_sensor, default_target, random_pose, target_scene
from scanrig.sim.flat_edges import FlatHits, planar_pixels, plane_points
from scanrig.sim.render import CameraView


def _uniform(h: int = 6, w: int = 7) -> tuple[np.ndarray, FlatHits]:
    """An (h, w) image that sees one lit plane z = 0.5 m everywhere."""
    n = h * w
    hits = FlatHits(np.tile([0.0, 0.0, 1.0], (n, 1)), np.full(n, 0.5), np.full(n, 80.0))
    return np.zeros((h, w), dtype=np.int64), hits


def test_interior_pixels_of_one_plane_are_planar_and_border_pixels_are_not():
    obj, hits = _uniform()
    pixels = np.arange(obj.size)
    row, col = np.divmod(pixels, obj.shape[1])
    interior = (row > 0) & (row < obj.shape[0] - 1) & (col > 0) & (col < obj.shape[1] - 1)
    np.testing.assert_array_equal(planar_pixels(pixels, obj, hits), interior)


@pytest.mark.parametrize("change", ["object", "normal", "offset", "shadow", "shiny or smooth", "miss"])
def test_a_neighbour_off_the_plane_or_in_other_light_makes_a_pixel_not_planar(change):
    obj, hits = _uniform()
    w = obj.shape[1]
    centre, corner_neighbour = 2 * w + 3, 3 * w + 4        # (2, 3) and its lower right neighbour
    if change == "object":
        obj.ravel()[corner_neighbour] = 1
    elif change == "normal":
        hits.normal[corner_neighbour] = [0.0, np.sin(1e-6), np.cos(1e-6)]
    elif change == "offset":
        hits.offset_m[corner_neighbour] += 1e-6
    elif change == "shadow":
        hits.lamp_W_m2[corner_neighbour] = 0.0
    else:
        hits.offset_m[corner_neighbour] = np.nan
        obj.ravel()[corner_neighbour] = -1 if change == "miss" else 0
    planar = planar_pixels(np.array([centre, 2 * w + 1]), obj, hits)
    assert not planar[0] and planar[1]     # (2, 1) has no neighbour in the change


def test_plane_points_lie_on_their_planes_along_their_rays():
    rng = np.random.default_rng(4)
    origin = np.array([0.1, -0.2, 0.3])
    normal = rng.normal(size=(5, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    offset = rng.uniform(-1, 1, 5)
    dirs = rng.normal(size=(5, 4, 3))
    p = plane_points(origin, dirs, normal, offset)
    np.testing.assert_allclose(np.einsum("nj,nmj->nm", normal, p), offset[:, None] * np.ones((1, 4)), atol=1e-12)
    cross = np.cross(p - origin, dirs)
    np.testing.assert_allclose(cross, 0.0, atol=1e-12)


def test_a_calibration_shot_is_the_same_with_and_without_the_closed_form_rays():
    """The shortcut casts fewer rays, not other ones: a cube shot in the default room (board
    edges, the cube's own edges, shadows, the room behind) is bit for bit the image that casting
    every sub-pixel ray gives, and most edge pixels took the shortcut."""
    room = load_scene("default")
    rig = default_rig(3, room.center_m, room.rig)
    target = default_target("cube")
    pose = random_pose(target, rig, room.center_m, room.radius_m, np.random.default_rng(0), room.rig.cover_field)
    scene = target_scene(target, pose, room)
    taken = []

    def counted(pixels, obj, hits):
        planar = planar_pixels(pixels, obj, hits)
        taken.append(planar.mean())
        return planar

    with mock.patch.object(render, "planar_pixels", counted):
        shortcut = CameraView(rig.cameras[0], scene, calibration_sensor(room)).background_e
    with mock.patch.object(render, "planar_pixels", lambda pixels, obj, hits: np.zeros(pixels.size, bool)):
        cast = CameraView(rig.cameras[0], scene, calibration_sensor(room)).background_e
    np.testing.assert_array_equal(shortcut, cast)
    assert 0.5 < taken[0] < 1.0
