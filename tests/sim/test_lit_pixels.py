"""The laser is rendered only in the pixels of its window that it may light, and nothing is lost."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from scanrig.sim import primitives
from scanrig.sim.laser import (
    FOOTPRINT_RADII,
    BeamPose,
    GaussianBeams,
    LaserTrace,
    trace_laser,
)
from scanrig.sim.lit_pixels import lit_pixels
from scanrig.sim.materials import Material
from scanrig.sim.render import CameraView, _subpixel_samples
from scanrig.sim.scene import SceneObject, place

from .conftest import plane_scene, small_rig

#: Light of a sheet or beam beyond the footprint cut, relative to its peak: exp(-2 · 3²).
TAIL = np.exp(-2.0 * FOOTPRINT_RADII**2)
#: Largest share of a window's pixels the stripe below may light (its sheet is a few pixels wide
#: in a window about four times as wide; a selection that prunes nothing fails).
MAX_LIT_SHARE = 0.6

STEEL = Material("steel", "metal", albedo=0.08, specular=0.6, roughness_rad=0.01)


def _scene():
    # a shiny upright plate on a matte floor: a stripe across both sends beamlets to the floor
    plate = SceneObject("plate", place(primitives.plane((0.15, 0.15)), (0.0, 0.05, 0.08), (90.0, 0.0, 0.0)), STEEL)
    return plane_scene(extra=(plate,))


def _stripe(scene, aim=(0.0, 0.05, 0.08)):
    head = np.asarray(scene.laser.head_m)
    d = np.asarray(aim) - head
    d /= np.linalg.norm(d)
    fan = np.cross(np.cross(d, [0.0, 0.0, 1.0]), d)
    return trace_laser(BeamPose(head, d, fan / np.linalg.norm(fan)), scene.laser, scene)


@dataclass
class _Case:
    """A stripe across a shiny plate seen by one camera: its window, the lit pixels, and each
    source's radiance at every sub-pixel sample, shape (pixels, s², sources)."""

    view: CameraView
    trace: LaserTrace
    mask: np.ndarray
    u0: int
    v0: int
    lit: np.ndarray
    alone: np.ndarray
    q: np.ndarray


@pytest.fixture(scope="module")
def case():
    scene = _scene()
    trace = _stripe(scene)
    view = CameraView(small_rig(1, center=(0.0, 0.0, 0.05)).cameras[0], scene)
    mask, u0, v0 = view.window_mask(trace)
    rows, cols = np.nonzero(mask)
    s = view.sensor.supersampling
    q = _subpixel_samples(np.column_stack([cols + u0, rows + v0]).astype(np.float64), s)
    alone = [view.laser_radiance(q, LaserTrace(sources=[src])).reshape(len(rows), s * s) for src in trace.sources]
    return _Case(view, trace, mask, u0, v0, lit_pixels(view, mask, u0, v0, trace.sources), np.stack(alone, axis=-1), q)


def test_the_stripe_has_many_beamlets_found_by_their_landings(case):
    beamlets = case.trace.sources[1]
    assert isinstance(beamlets, GaussianBeams) and beamlets.landing is not None and len(beamlets.power_W) > 8


def test_pixels_left_out_get_no_light_above_the_footprint_cut(case):
    sheet, beamlets = case.alone[..., 0], case.alone[..., 1]
    assert sheet.max() > 0 and beamlets.max() > 0
    assert sheet[~case.lit[:, 0]].max() <= TAIL * sheet.max()
    # each beamlet is cut at its footprint too (and lights nothing beyond its reach of its landing)
    assert beamlets[~case.lit[:, 1]].max() <= TAIL * beamlets.max()


def test_most_of_the_window_is_left_out(case):
    assert case.lit.any(axis=1).mean() < MAX_LIT_SHARE


def test_selected_rendering_equals_the_full_one_where_it_renders(case):
    s2 = case.alone.shape[1]
    full = case.view.laser_radiance(case.q, case.trace).reshape(-1, s2)
    some = case.lit.any(axis=1)
    q = case.q.reshape(-1, s2, 2)[some].reshape(-1, 2)
    sel = case.view.laser_radiance(q, case.trace, np.repeat(case.lit[some], s2, axis=0))
    expected = np.where(case.lit[some][:, None, :], case.alone[some], 0.0).sum(axis=-1)
    np.testing.assert_allclose(sel.reshape(-1, s2), expected, rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(full[~some], 0.0, atol=TAIL * full.max())


def test_depth_steps_and_silhouettes_are_always_rendered(case):
    # pixels whose centre sees the plate beside one that sees the floor: rendered whatever the laser
    rows, cols = np.nonzero(case.mask)
    table = case.view.ray_table
    obj = case.view.scene.raycaster.cast(np.broadcast_to(table.origin, (len(rows), 3)),
                                         table.to_world(table.xy[rows + case.v0, cols + case.u0])).obj
    grid = np.full(case.mask.shape, -2)
    grid[rows, cols] = obj
    right = np.zeros(case.mask.shape, dtype=bool)
    right[:, :-1] = (grid[:, :-1] != grid[:, 1:]) & (grid[:, 1:] != -2)
    boundary = right[rows, cols]
    sheet, beamlets = case.alone[..., 0], case.alone[..., 1]
    dark = (sheet.max(axis=1) <= TAIL * sheet.max()) & (beamlets.max(axis=1) == 0.0)
    assert (boundary & dark).any()          # some of them the laser does not light
    assert case.lit[boundary].all()
