"""rig.toml: exact round trip, camera order, errors naming the file and field."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import scanrig
from scanrig.errors import FileFormatError
from scanrig.geometry import Camera, Rig, RigidTransform
from scanrig.io.rig_file import load_rig_info, save_rig

finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6)


def make_rig(rng, names=("cam0", "cam10", "cam2")):
    cams = []
    for name in names:
        params = np.r_[rng.uniform(500, 3000, 2), rng.uniform(300, 700, 2), rng.normal(0, 0.1, 8)]
        pose = RigidTransform.from_rvec_tvec(rng.normal(size=3), rng.normal(size=3))
        cams.append(Camera(name, "opencv8", params, 1280, 1024, pose))
    return Rig(cams)


def assert_same_rig(a, b):
    assert a.names == b.names
    for ca, cb in zip(a.cameras, b.cameras):
        assert ca.model == cb.model and (ca.width, ca.height) == (cb.width, cb.height)
        assert np.array_equal(ca.params, cb.params)
        assert np.array_equal(ca.cam_from_world.R, cb.cam_from_world.R)
        assert np.array_equal(ca.cam_from_world.t, cb.cam_from_world.t)


def test_round_trip_is_bit_exact_and_keeps_order(tmp_path):
    rig = make_rig(np.random.default_rng(1))
    path = tmp_path / "rig.toml"
    scanrig.save_rig(rig, path, camera_info={"cam0": {"rms_px": 0.12, "n_observations": 480}},
                     metadata={"seed": 7, "command": "scanrig calibrate S"}, comments=["written by a test"])
    again, info, meta = load_rig_info(path)
    assert_same_rig(rig, again)
    assert info["cam0"] == {"rms_px": 0.12, "n_observations": 480} and info["cam10"] == {}
    assert meta == {"seed": 7, "command": "scanrig calibrate S"}
    assert path.read_text().startswith("# written by a test\n")


@settings(max_examples=100, deadline=None)
@given(params=st.lists(finite, min_size=9, max_size=9), f=st.floats(1e-3, 1e6))
def test_round_trip_exact_for_any_float(tmp_path_factory, params, f):
    params = [f, f] + params[2:]
    cam = Camera("c", "opencv5", params, 10, 10)
    path = tmp_path_factory.mktemp("rig") / "rig.toml"
    save_rig(Rig([cam]), path)
    assert np.array_equal(scanrig.load_rig(path)["c"].params, cam.params)


GOOD = """format_version = 1
units = "m"
[[cameras]]
name = "cam0"
model = "opencv5"
width = 1280
height = 1024
params = [1000.0, 1000.0, 640.0, 512.0, 0.0, 0.0, 0.0, 0.0, 0.0]
R_cam_from_world = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
t_cam_from_world = [0.0, 0.0, 0.0]
"""


@pytest.mark.parametrize(
    "edit,message",
    [
        (lambda s: s.replace('width = 1280\n', ''), r"\[\[cameras\]\] #1: missing field 'width'"),
        (lambda s: s.replace('"opencv5"', '"opencv7"'), r"model must be one of .* got 'opencv7'"),
        (lambda s: s.replace("height = 1024", "height = -1024"), r"height must be a positive integer, got -1024"),
        (lambda s: s.replace("width = 1280", "widht = 1280"), r"unknown field 'widht' \(did you mean 'width'\?\)"),
        (lambda s: s.replace("format_version = 1", "format_version = 2"), r"format_version must be 1, got 2"),
        (lambda s: s.replace('units = "m"', 'units = "mm"'), r'units must be "m", got \'mm\''),
        (lambda s: s.replace("0.0, 0.0, 0.0]\n", "0.0]\n", 1), r"params \(opencv5\) must have shape \(9,\)"),
        (lambda s: s.replace("[1.0, 0.0, 0.0], [0.0, 1.0", "[2.0, 0.0, 0.0], [0.0, 1.0"), r"proper rotation"),
        (lambda s: s + s[s.index("[[cameras]]"):], r"camera names must be unique in a rig, duplicated: \['cam0'\]"),
        (lambda s: s.replace("[[cameras]]", "[[cameras"), r"not valid TOML"),
        (lambda s: s.replace("t_cam_from_world = [0.0, 0.0, 0.0]", "t_cam_from_world = [0.0, nan, 0.0]"), r"t must be finite"),
    ],
)
def test_bad_rig_files_name_file_and_field(tmp_path, edit, message):
    path = tmp_path / "rig.toml"
    path.write_text(edit(GOOD))
    with pytest.raises(FileFormatError, match=message) as err:
        scanrig.load_rig(path)
    assert str(err.value).startswith(str(path))


def test_missing_rig_file(tmp_path):
    with pytest.raises(FileFormatError, match="rig.toml: file not found"):
        scanrig.load_rig(tmp_path / "rig.toml")
