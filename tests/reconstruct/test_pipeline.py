"""``reconstruct_session`` and ``scanrig reconstruct``: files in, points.ply out, clear errors."""

import numpy as np
import pytest

from scanrig.cli.main import main
from scanrig.errors import FileFormatError, InputError
from scanrig.geometry import Rig
from scanrig.io.rig_file import save_rig
from scanrig.io.session import write_image
from scanrig.laser.traces import empty_table, write_traces
from scanrig.reconstruct.flags import Flag
from scanrig.reconstruct.pipeline import reconstruct_session
from scanrig.reconstruct.points import POINT_FIELDS, UNITS_COMMENT, read_points
from tests.reconstruct.synth import HEIGHT, WIDTH, points_in_cube, ring_rig, spot_traces, two_camera_table

SIGMA_PX = 0.3
#: With 0.3 px noise (+0.1 px floor) the points' 3-D error is ~0.2 mm RMS; 0.5 mm is 2.5x that.
RMS_TOL_M = 5e-4


def _session(tmp_path, rig=None, n_frames=40, seed=41):
    rng = np.random.default_rng(seed)
    rig = rig or ring_rig()
    save_rig(rig, tmp_path / "rig.toml")
    p_true = points_in_cube(rng, n_frames)
    table, _ = spot_traces(rig, p_true, rng, SIGMA_PX, reflection_rate=0.2)
    write_traces(tmp_path / "traces.parquet", table, {})
    return p_true


def test_session_to_points_ply(tmp_path):
    p_true = _session(tmp_path)
    summary = reconstruct_session(tmp_path, seed=41, comments=("scanrig test",))
    cloud, comments = read_points(tmp_path / "points.ply")
    assert summary["points"] == len(cloud) > 35
    assert UNITS_COMMENT in comments and "scanrig test" in comments
    assert [c for c in comments if c.startswith("seed:")] == ["seed: 41"]
    err = cloud.p_world - p_true[cloud.frame]
    assert np.sqrt(np.mean(np.sum(err**2, axis=1))) < RMS_TOL_M
    assert np.all(cloud.sigma > 0) and np.all(cloud.n_views >= 2)


def test_points_ply_is_binary_little_endian_with_the_contract_fields(tmp_path):
    _session(tmp_path, n_frames=5)
    reconstruct_session(tmp_path)
    header = (tmp_path / "points.ply").read_bytes().split(b"end_header")[0].decode()
    assert "format binary_little_endian 1.0" in header
    types = {"float64": "double", "uint8": "uchar", "float32": "float", "int32": "int", "uint16": "ushort"}
    for name, dtype in POINT_FIELDS:
        assert f"property {types[np.dtype(dtype).name]} {name}" in header


def test_cli_reconstruct_and_evaluate_exit_codes(tmp_path, capsys):
    _session(tmp_path, n_frames=10)
    assert main(["reconstruct", str(tmp_path)]) == 0
    assert "points from 10 frames (spot, seed 0)" in capsys.readouterr().out
    assert main(["reconstruct", str(tmp_path / "nowhere")]) == 2
    assert "session folder not found" in capsys.readouterr().err


def test_single_camera_rig_is_refused(tmp_path):
    _session(tmp_path)
    save_rig(Rig(ring_rig().cameras[:1]), tmp_path / "rig.toml")
    with pytest.raises(InputError, match=r"rig.toml: multi-view reconstruction needs at least 2 cameras, "
                                         r"the rig has 1 \(\['cam0'\]\)"):
        reconstruct_session(tmp_path)


def test_traces_of_cameras_missing_from_the_rig(tmp_path):
    _session(tmp_path)
    save_rig(Rig(ring_rig().cameras[:2]), tmp_path / "rig.toml")
    with pytest.raises(InputError, match=r"traces name cameras \['cam2'\] that are not in the rig"):
        reconstruct_session(tmp_path)


def test_missing_or_empty_traces(tmp_path):
    save_rig(ring_rig(), tmp_path / "rig.toml")
    with pytest.raises(FileFormatError, match=r"traces.parquet: traces file not found \(run `scanrig detect` first\)"):
        reconstruct_session(tmp_path)
    write_traces(tmp_path / "traces.parquet", empty_table(), {})
    with pytest.raises(FileFormatError, match=r"traces.parquet: holds no traces"):
        reconstruct_session(tmp_path)


def test_missing_rig(tmp_path):
    with pytest.raises(FileFormatError, match=r"rig.toml: rig file not found \(run `scanrig calibrate` first"):
        reconstruct_session(tmp_path)


def test_rig_and_images_must_agree(tmp_path):
    _session(tmp_path, n_frames=3)
    for name in ("cam0", "cam1", "cam2"):
        (tmp_path / "scan" / name).mkdir(parents=True)
        write_image(tmp_path / "scan" / name / "f0000.png", np.zeros((HEIGHT, WIDTH), np.uint8))
    reconstruct_session(tmp_path)  # consistent: fine
    write_image(tmp_path / "scan" / "cam1" / "f0000.png", np.zeros((48, 64), np.uint8))
    with pytest.raises(FileFormatError, match=r"rig.toml: camera 'cam1' is 1280x1024 but scan/cam1/f0000.png is 64x48"):
        reconstruct_session(tmp_path)
    (tmp_path / "scan" / "cam7").mkdir()
    with pytest.raises(FileFormatError, match=r"rig.toml: has no camera \['cam7'\] for the scan folders"):
        reconstruct_session(tmp_path)


def test_ambiguous_points_are_kept_only_on_request(tmp_path):
    """Two cameras, two spots in one frame: both pairings agree, so the frame is ambiguous."""
    rig = Rig(ring_rig().cameras[:2])
    save_rig(rig, tmp_path / "rig.toml")
    p = np.array([[0.05, 0.0, 0.0], [-0.05, 0.02, 0.05]])
    table = two_camera_table({cam.name: cam.project(p) for cam in rig.cameras})
    write_traces(tmp_path / "traces.parquet", table, {})
    summary = reconstruct_session(tmp_path)
    strict, _ = read_points(tmp_path / "points.ply")
    assert summary["frames_ambiguous"] == 1 and len(strict) == 0
    reconstruct_session(tmp_path, keep_ambiguous=True)
    cloud, _ = read_points(tmp_path / "points.ply")
    assert len(cloud) == 1 and cloud.flags[0] & Flag.AMBIGUOUS
