"""Classic single-camera mode with ``scan/object_poses.csv``: each frame's profile in the object frame."""

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scanrig.errors import FileFormatError
from scanrig.geometry import Rig, RigidTransform
from scanrig.io.object_poses import object_poses_path, write_object_poses
from scanrig.io.rig_file import save_rig
from scanrig.laser.traces import write_traces
from scanrig.reconstruct.light_plane import fit_plane, save_light_plane
from scanrig.reconstruct.pipeline import reconstruct_session
from scanrig.reconstruct.points import read_points
from tests.reconstruct.synth import ring_rig, stripe_traces

#: Round-off of a rigid motion of points ~1 m from the origin, metres.
ROUND_OFF_M = 1e-12


def _session(tmp_path):
    """A one-camera session (traces only: no images) with three stripe frames and its light plane x = 0.05."""
    rng = np.random.default_rng(76)
    cam = ring_rig(height_m=0.6).cameras[0]
    save_rig(Rig([cam]), tmp_path / "rig.toml")
    (tmp_path / "scan" / cam.name).mkdir(parents=True)
    table = stripe_traces(Rig([cam]), [0.05, 0.05, 0.05], rng, 0.2)
    write_traces(tmp_path / "traces.parquet", table, {})
    grid = np.stack(np.meshgrid([0.0, 0.1], [0.0, 0.1]), -1).reshape(-1, 2)
    save_light_plane(tmp_path / "light_plane.toml", fit_plane(np.c_[np.full(4, 0.05), grid]), cam.name)
    return sorted(set(table.column("frame").to_pylist()))


def test_points_are_mapped_into_the_object_frame_of_their_frame(tmp_path):
    stems = _session(tmp_path)
    plane = tmp_path / "light_plane.toml"
    reconstruct_session(tmp_path, light_plane_path=plane, out_path=tmp_path / "world.ply")
    world, _ = read_points(tmp_path / "world.ply")
    rng = np.random.default_rng(5)
    poses = {stem: RigidTransform(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3) * 0.1)
             for stem in stems}
    write_object_poses(object_poses_path(tmp_path), poses)
    summary = reconstruct_session(tmp_path, light_plane_path=plane, out_path=tmp_path / "object.ply")
    obj, comments = read_points(tmp_path / "object.ply")
    assert "object frame of scan/object_poses.csv" in summary["mode"]
    assert len(set(world.frame.tolist())) == len(stems) and np.array_equal(obj.frame, world.frame)
    for k, stem in enumerate(stems):
        rows = world.frame == k
        expected = poses[stem].inverse().apply(world.p_world[rows])
        np.testing.assert_allclose(obj.p_world[rows], expected, rtol=0, atol=ROUND_OFF_M)
    np.testing.assert_array_equal(obj.sigma, world.sigma)


def test_a_frame_without_a_pose_is_an_error(tmp_path):
    stems = _session(tmp_path)
    path = object_poses_path(tmp_path)
    write_object_poses(path, {stems[0]: RigidTransform.identity()})
    message = (f"{path}: has no pose for 2 scan frame(s) with points, e.g. {stems[1:]}; "
               f"give world_from_object of every frame")
    with pytest.raises(FileFormatError, match=f"^{re.escape(message)}$"):
        reconstruct_session(tmp_path, light_plane_path=tmp_path / "light_plane.toml")
    assert not (tmp_path / "points.ply").exists()
