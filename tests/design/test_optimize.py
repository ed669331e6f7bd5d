"""Camera search: gains add up, the design beats a ring where the ring is poor, bad inputs are refused."""

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from scanrig.design import MeshError, MountingError, TargetError, design_rig
from scanrig.design.spec import MountingSpec, TargetSpec
from scanrig.errors import InputError

from .scenes import sheet, small_spec


def wall() -> trimesh.Trimesh:
    """A 0.12 m square sheet standing upright at the origin, facing +y (seen only from one side)."""
    mesh = sheet(0.12, 16)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    mesh.apply_translation([0.0, 0.0, 0.06])
    return mesh


@pytest.fixture(scope="module")
def wall_design():
    return design_rig(wall(), 3, small_spec(), np.random.default_rng(2), search_elements=3000, allow_open=True)


def test_wall_faces_plus_y(wall_design):
    assert np.allclose(wall().face_normals, [0.0, 1.0, 0.0])


def test_gains_add_up_to_the_covered_fraction(wall_design):
    steps = wall_design.selection.steps
    assert sum(s.gain for s in steps) == pytest.approx(wall_design.selection.covered_fraction, abs=1e-12)
    covered = [s.covered_fraction for s in steps]
    assert covered == sorted(covered)                        # adding a camera never loses coverage
    assert all(s.loss_if_removed >= 0 for s in steps)
    assert steps[0].gain == 0.0                              # one camera cannot triangulate


def test_design_beats_the_ring_on_a_one_sided_object(wall_design):
    a, ring = wall_design.analysis, wall_design.ring
    assert a.covered_fraction > 0.9
    assert ring.covered_fraction < a.covered_fraction
    centers = np.array([c.center_world for c in wall_design.rig.cameras])
    assert np.all(centers[:, 1] > 0)                         # every camera on the side the wall faces


def test_search_and_full_analysis_agree(wall_design):
    """The search ran on sampled points, the analysis on every face: same fraction within sampling error."""
    n = 3000
    p = wall_design.selection.covered_fraction
    assert wall_design.analysis.covered_fraction == pytest.approx(p, abs=5 * np.sqrt(p * (1 - p) / n) + 1e-9)


def test_target_below_the_speckle_limit_gives_the_best_figure():
    with pytest.raises(TargetError, match=r"\[target\] sigma_m 1e-07 m is below the speckle limit of these optics: "
                                          r"the best achievable with 3 cameras is [0-9.e-]+ m") as err:
        design_rig(wall(), 3, small_spec(sigma_m=1e-7), np.random.default_rng(0), search_elements=500, allow_open=True)
    assert 1e-7 < err.value.best_achievable_m < 1e-4


def test_more_cameras_than_positions():
    spec = small_spec()
    spec = replace(spec, mounting=replace(spec.mounting, n_candidates=2))
    with pytest.raises(InputError, match="cameras: 3 requested but the mounting region has only 2 candidate positions"):
        design_rig(wall(), 3, spec, np.random.default_rng(0), search_elements=500, allow_open=True)


def test_region_that_never_sees_the_object():
    spec = small_spec()
    spec = replace(spec, mounting=MountingSpec(radius_m=(0.5, 0.7), height_m=(0.1, 0.5), look_at=(3.0, 3.0, 0.0),
                                               n_candidates=12))
    with pytest.raises(MountingError, match=r"\[mounting\]: no candidate camera sees any part of the object"):
        design_rig(wall(), 2, spec, np.random.default_rng(0), search_elements=500, allow_open=True)


def test_too_few_cameras():
    with pytest.raises(InputError, match=r"cameras must be an integer >= 2 \(target min_views\), got 1"):
        design_rig(wall(), 1, small_spec(), np.random.default_rng(0))


def test_tighter_target_covers_less(wall_design):
    spec = replace(wall_design.spec, target=TargetSpec(sigma_m=np.median(wall_design.analysis.sigma_m)))
    tight = design_rig(wall(), 3, spec, np.random.default_rng(2), search_elements=3000, compare_ring=False,
                       allow_open=True)
    assert tight.analysis.covered_fraction <= wall_design.analysis.covered_fraction


def test_one_sided_sheet_needs_allow_open():
    with pytest.raises(MeshError, match=r"wall.stl: 100.0 % of the surface .* is seen from behind .* \(--allow-open\)"):
        design_rig(wall(), 2, small_spec(), np.random.default_rng(0), mesh_name="wall.stl", search_elements=500)


def test_two_lenses_never_share_a_mount():
    spec = small_spec()
    spec = replace(spec, camera=replace(spec.camera, focal_lengths_m=(0.008, 0.012)),
                   mounting=replace(spec.mounting, n_candidates=10))
    design = design_rig(wall(), 3, spec, np.random.default_rng(2), search_elements=1500, allow_open=True,
                        compare_ring=False)
    poses = [s.candidate.pose_id for s in design.selection.steps]
    assert len(set(poses)) == 3
    assert {round(1e3 * s.candidate.focal_length_m) for s in design.selection.steps} <= {8, 12}


def test_candidates_inside_the_object_are_dropped():
    """Near the end of a 5 m bar, 11 of 12 candidates are inside it: too few left for 2 cameras."""
    bar = trimesh.creation.box((5.0, 0.2, 0.2))
    spec = replace(small_spec(), mounting=MountingSpec(radius_m=(0.05, 0.08), height_m=(0.0, 0.05),
                                                       look_at=(2.45, 0.0, 0.0), n_candidates=12))
    with pytest.raises(InputError, match="cameras: 2 requested but the mounting region has only 1 candidate positions"):
        design_rig(bar, 2, spec, np.random.default_rng(0), search_elements=500)
