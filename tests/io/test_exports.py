"""Exports: OpenCV YAML (round trip through cv2.FileStorage), mrcal .cameramodel, COLMAP text."""

import ast

import cv2
import numpy as np
import pytest

from scanrig.errors import FileFormatError
from scanrig.geometry import Camera, Rig
from scanrig.io.colmap_text import export_colmap_text
from scanrig.io.mrcal_model import cameramodel_text, export_cameramodels
from scanrig.io.opencv_yaml import export_opencv_yaml, import_opencv_yaml
from tests.data_paths import real_data
from tests.io.test_rig_file import assert_same_rig, make_rig


def test_opencv_yaml_round_trip_is_exact_and_cv2_reads_it(tmp_path):
    rig = make_rig(np.random.default_rng(2))
    path = tmp_path / "rig.yml"
    export_opencv_yaml(rig, path)
    assert_same_rig(rig, import_opencv_yaml(path))
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    K, _, _, _ = rig["cam10"].to_opencv()
    assert np.array_equal(fs.getNode("camera_1").getNode("camera_matrix").mat(), K)
    assert fs.getNode("camera_1").getNode("name").string() == "cam10"


def test_imports_opencv_calibration_sample_output():
    rig = import_opencv_yaml(real_data("opencv-stereo-9x6") / "left_intrinsics.yml", name="left")
    cam = rig["left"]
    # Reference values from the file's PROVENANCE.md (OpenCV's published result).
    assert (cam.width, cam.height, cam.model) == (640, 480, "opencv5")
    np.testing.assert_allclose(cam.params[:5], [535.91573396163199, 535.91573396163199,
                                                342.28315473308373, 235.57082909788173,
                                                -0.26637260909660682], rtol=0, atol=0)


def test_import_names_missing_node(tmp_path):
    path = tmp_path / "bad.yml"
    path.write_text("%YAML:1.0\n---\nimage_width: 640\n")
    with pytest.raises(FileFormatError, match="expected a 'camera_count' node"):
        import_opencv_yaml(path)


@pytest.mark.parametrize("model,n", [("pinhole", 0), ("opencv4", 4), ("opencv5", 5), ("opencv8", 8), ("opencv12", 12)])
def test_mrcal_cameramodel_parses_with_documented_order(model, n):
    rng = np.random.default_rng(n)
    params = np.r_[1500.0, 1510.0, 640.5, 511.25, rng.normal(0, 0.05, n)]
    cam = Camera("c", model, params, 1280, 1024)
    doc = ast.literal_eval(cameramodel_text(cam, ("a comment",)).split("\n", 1)[1])
    assert doc["lensmodel"] == {"pinhole": "LENSMODEL_PINHOLE"}.get(model, f"LENSMODEL_OPENCV{n}")
    # mrcal: intrinsics = fx fy cx cy then OpenCV's distortion order; extrinsics = rt_cam_ref.
    assert doc["intrinsics"] == params.tolist()
    assert doc["extrinsics"] == [*cam.cam_from_world.rvec, *cam.cam_from_world.t]
    assert doc["imagersize"] == [1280, 1024]


def test_mrcal_export_writes_one_file_per_camera(tmp_path):
    paths = export_cameramodels(make_rig(np.random.default_rng(4)).cameras, tmp_path)
    assert [p.name for p in paths] == ["cam0.cameramodel", "cam10.cameramodel", "cam2.cameramodel"]


def test_colmap_text_shifts_principal_point_and_stores_quaternion(tmp_path):
    cam = Camera.from_opencv("c", [[1000, 0, 640], [0, 1001, 512], [0, 0, 1]], [-0.1, 0.01, 0.001, 0.002],
                             [0.1, 0.2, 0.3], [1, 2, 3], 1280, 1024)
    cams_txt, imgs_txt = export_colmap_text(Rig([cam]), tmp_path)
    fields = cams_txt.read_text().splitlines()[-1].split()
    assert fields[:4] == ["1", "OPENCV", "1280", "1024"]
    assert [float(x) for x in fields[4:8]] == [1000.0, 1001.0, 640.5, 512.5]
    q = [float(x) for x in imgs_txt.read_text().splitlines()[3].split()[1:5]]
    from scipy.spatial.transform import Rotation
    R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    np.testing.assert_allclose(R, cam.cam_from_world.R, atol=1e-15)
