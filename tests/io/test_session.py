"""Session folders: camera order, frames, images, atomic writes."""

import numpy as np
import pytest

from scanrig.errors import FileFormatError
from scanrig.io.atomic import atomic_write, write_text_atomic
from scanrig.io.session import Session, read_image, write_image


def make_session(root, cams=("cam10", "cam2", "cam1"), stems=("f1", "f2")):
    for cam in cams:
        (root / "scan" / cam).mkdir(parents=True)
        for stem in stems:
            write_image(root / "scan" / cam / f"{stem}.png", np.full((4, 6), 7, np.uint8))
    return Session(root)


def test_cameras_sorted_naturally_without_session_toml(tmp_path):
    assert make_session(tmp_path).camera_names("scan") == ["cam1", "cam2", "cam10"]


def test_session_toml_order_wins(tmp_path):
    s = make_session(tmp_path)
    (tmp_path / "session.toml").write_text('cameras = ["cam10", "cam1", "cam2"]\n')
    assert s.camera_names("scan") == ["cam10", "cam1", "cam2"]
    (tmp_path / "session.toml").write_text('cameras = ["cam10", "cam3"]\n')
    with pytest.raises(FileFormatError, match=r"camera folders \['cam3'\] named in session.toml are missing"):
        s.camera_names("scan")


def test_frames_and_images_round_trip(tmp_path):
    s = make_session(tmp_path, cams=("a",), stems=("f10", "f9", "dark"))
    assert list(s.frames("scan")) == ["f9", "f10"]
    assert s.dark_path("a").name == "dark.png"
    img16 = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000)
    write_image(tmp_path / "x.png", img16)
    assert np.array_equal(read_image(tmp_path / "x.png"), img16)
    rgb = np.zeros((3, 4, 3), np.uint8)
    rgb[..., 0] = 200
    write_image(tmp_path / "c.png", rgb)
    assert np.array_equal(read_image(tmp_path / "c.png"), rgb)


@pytest.mark.parametrize(
    "content,message",
    [(b"", "image file is empty"), (b"\x89PNG\r\n\x1a\n garbage", "cannot decode image")],
)
def test_bad_images_name_the_file(tmp_path, content, message):
    path = tmp_path / "bad.png"
    path.write_bytes(content)
    with pytest.raises(FileFormatError, match=message) as err:
        read_image(path)
    assert str(path) in str(err.value)


def test_missing_stage_folder(tmp_path):
    with pytest.raises(FileFormatError, match="calibration folder not found in session"):
        Session(tmp_path).camera_names("calibration")


def test_atomic_write_keeps_previous_file_on_crash(tmp_path):
    path = tmp_path / "out.txt"
    write_text_atomic(path, "old")
    with pytest.raises(RuntimeError):
        with atomic_write(path, "w") as f:
            f.write("half")
            raise RuntimeError("crash mid-write")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_file_format_error_survives_pickling():
    import pickle

    err = pickle.loads(pickle.dumps(FileFormatError("/x/y.png", "cannot decode image")))
    assert isinstance(err, FileFormatError) and str(err) == "/x/y.png: cannot decode image"
