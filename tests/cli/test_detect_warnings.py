"""``scanrig detect`` prints a frame whose scene reaches the clip level as one ``warning:`` line."""

import pytest

from scanrig.cli.main import main
from scanrig.io.session import write_image
from tests.laser.test_bright_scene import AT, NORMAL, frames


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_bright_frame_is_one_warning_line(tmp_path, capsys, workers):
    # before: Python's format, "<path>/cli/detect.py:63: BrightSceneWarning: ..." and a source line
    for camera, paper in (("cam0", NORMAL), ("cam1", AT)):
        (tmp_path / "scan" / camera).mkdir(parents=True)
        write_image(tmp_path / "scan" / camera / "00012.png", frames(paper)[0])
    assert main(["detect", str(tmp_path), "--mode", "stripe", "--color", "red", "--workers", workers]) == 0
    assert capsys.readouterr().err.splitlines() == [
        "warning: camera 'cam1' frame '00012': the scene itself is within 9% of the red channel's clip level "
        "(255 DN) on 91% of the frame, where the laser cannot show: lower the exposure or the gain"]
