"""PLY reader and writer."""

import numpy as np
import plyfile
import pytest

from scanrig.errors import FileFormatError, InputError
from scanrig.io.ply import read_ply, read_points, write_ply


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_round_trip_with_extra_fields_faces_and_comments(tmp_path, binary, dtype):
    rng = np.random.default_rng(3)
    n = 50
    vertices = {"x": rng.normal(size=n).astype(dtype), "y": rng.normal(size=n).astype(dtype),
                "z": rng.normal(size=n).astype(dtype), "inlier": rng.random(n) < 0.5,
                "score": rng.random(n).astype(np.float32)}
    faces = rng.integers(0, n, size=(20, 3))
    path = tmp_path / "a.ply"
    write_ply(path, vertices, faces=faces, comments=["seed 7", "units m"], binary=binary)
    got, got_faces, comments = read_ply(path)
    assert list(got) == list(vertices)
    for name, v in vertices.items():
        np.testing.assert_array_equal(got[name], v.astype(np.uint8) if v.dtype == bool else v)
    assert got["x"].dtype == dtype
    np.testing.assert_array_equal(got_faces, faces)
    assert comments == ["seed 7", "units m"]
    np.testing.assert_array_equal(read_points(path), np.column_stack([vertices[k] for k in "xyz"]).astype(float))
    assert not list(tmp_path.glob(".*.tmp"))  # the atomic writer cleaned up


def test_missing_field_is_named(tmp_path):
    path = tmp_path / "no_z.ply"
    table = np.zeros(3, dtype=[("x", "f4"), ("y", "f4")])
    plyfile.PlyData([plyfile.PlyElement.describe(table, "vertex")]).write(str(path))
    with pytest.raises(FileFormatError, match=r"no_z\.ply.*\bz\b"):
        read_ply(path)


def test_missing_and_garbage_files(tmp_path):
    with pytest.raises(FileFormatError, match="no such file"):
        read_ply(tmp_path / "absent.ply")
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"not a ply at all\n")
    with pytest.raises(FileFormatError, match="bad.ply"):
        read_ply(bad)


def test_writer_rejects_bad_input(tmp_path):
    with pytest.raises(InputError):
        write_ply(tmp_path / "a.ply", {"x": np.zeros(3), "y": np.zeros(4)})
    with pytest.raises(InputError):
        write_ply(tmp_path / "a.ply", {"x": np.zeros(3)}, faces=np.array([[0, 1, 5]]))
    with pytest.raises(InputError):
        write_ply(tmp_path / "a.ply", {"x": np.zeros(3)}, comments=["two\nlines"])
    assert not (tmp_path / "a.ply").exists()
