"""``scan/object_poses.csv``: round trip, rounding tolerance and the exact errors on bad files."""

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scanrig.errors import FileFormatError, InputError
from scanrig.geometry import RigidTransform
from scanrig.io.object_poses import COLUMNS, read_object_poses, write_object_poses

HEADER = ",".join(COLUMNS)


def _poses(n: int) -> dict:
    rng = np.random.default_rng(3)
    return {f"{i:05d}": RigidTransform(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))
            for i in range(n)}


def test_round_trip_is_exact(tmp_path):
    poses = _poses(5)
    write_object_poses(tmp_path / "object_poses.csv", poses)
    back = read_object_poses(tmp_path / "object_poses.csv")
    assert list(back) == list(poses)
    for stem, pose in poses.items():
        np.testing.assert_allclose(back[stem].as_matrix(), pose.as_matrix(), rtol=0, atol=1e-15)


def test_seven_printed_digits_are_accepted_and_made_a_rotation(tmp_path):
    pose = _poses(1)["00000"]
    cells = [f"{v:.7f}" for v in (*pose.R.ravel(), *pose.t)]
    (tmp_path / "p.csv").write_text(f"{HEADER}\n00000,{','.join(cells)}\n")
    R = read_object_poses(tmp_path / "p.csv")["00000"].R
    np.testing.assert_allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-12)
    # 7 digits round each entry by at most 5e-8; the nearest rotation moves it by about as much
    np.testing.assert_allclose(R, pose.R, rtol=0, atol=2e-7)


@pytest.mark.parametrize(("row", "message"), [
    ("00000,1,0,0,0,1,0,0,0,1,0,0,x", "line 2: every cell but 'frame' must be a number"),
    ("00000,1,0,0,0,1,0,0,0,1,0,0,nan", "line 2: cells must be finite numbers"),
    ("00000,1,0,0,0,1,0,0,0,-1,0,0,0", "line 2: r00..r22 of frame '00000' are not a proper rotation "
                                       "(orthonormal to 1e-06, determinant +1)"),
    ("00000,1.001,0,0,0,1,0,0,0,1,0,0,0", "line 2: r00..r22 of frame '00000' are not a proper rotation "
                                          "(orthonormal to 1e-06, determinant +1)"),
    (",1,0,0,0,1,0,0,0,1,0,0,0", "line 2: empty frame stem"),
    ("00000,1,0,0,0,1,0,0,0,1,0,0,0\n00000,1,0,0,0,1,0,0,0,1,0,0,0", "line 3: frame '00000' is listed twice"),
])
def test_bad_rows_name_the_file_and_line(tmp_path, row, message):
    path = tmp_path / "object_poses.csv"
    path.write_text(f"{HEADER}\n{row}\n")
    with pytest.raises(FileFormatError, match=f"^{re.escape(f'{path}: {message}')}$"):
        read_object_poses(path)


def test_missing_column_empty_and_missing_file(tmp_path):
    path = tmp_path / "object_poses.csv"
    path.write_text("frame,r00\n00000,1\n")
    with pytest.raises(FileFormatError, match=re.escape(f"{path}: missing column(s) ['r01',")):
        read_object_poses(path)
    path.write_text(f"{HEADER}\n")
    with pytest.raises(FileFormatError, match=f"^{re.escape(f'{path}: holds no poses')}$"):
        read_object_poses(path)
    with pytest.raises(FileFormatError, match=re.escape(f"{tmp_path / 'none.csv'}: object poses file not found")):
        read_object_poses(tmp_path / "none.csv")
    with pytest.raises(InputError, match="^write_object_poses needs at least one pose$"):
        write_object_poses(path, {})
