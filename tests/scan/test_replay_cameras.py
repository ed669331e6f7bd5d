"""Replay rig over a recorded scan, and OpenCV VideoCapture cameras over video files."""

import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.scan.cameras import VideoCaptureCameras
from scanrig.scan.loop import run_scan
from scanrig.scan.processing import SpotProcessor
from scanrig.scan.protocol import Beam, Cameras, LaserPositioner, RigError
from scanrig.scan.replay import ReplayRig
from scanrig.scan.store import ScanStore
from tests.scan import fakerig
from tests.scan.test_loop import BUDGET, CONFIG, SEED, _scan, _xyz

#: MJPG is lossy: a flat grey frame comes back within a few DN of what was written.
MJPG_DN_TOL = 4.0


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    root = tmp_path_factory.mktemp("recorded")
    return root, _scan(root)


def test_replay_reproduces_the_recorded_scan(recorded, tmp_path):
    root, result = recorded
    replay = ReplayRig(root)
    assert isinstance(replay, Cameras) and isinstance(replay, LaserPositioner)
    store = ScanStore.create(tmp_path, replay.names, {"seed": SEED})
    again = run_scan(store, replay, replay, CONFIG, SpotProcessor(fakerig.make_rig(), dark=store.dark_paths()),
                     np.random.default_rng(SEED), BUDGET)
    np.testing.assert_array_equal(_xyz(again), _xyz(result))
    assert store.state.beams == ScanStore.open(root).state.beams


def test_replay_refuses_a_different_beam_in_strict_mode(recorded):
    replay = ReplayRig(recorded[0])
    with pytest.raises(RigError, match=r"replay: the beam commanded for frame 0 differs from the recorded one"):
        replay.move_to(Beam(np.zeros(3), np.array([0.0, 0.0, -1.0])))
    loose = ReplayRig(recorded[0], strict=False)
    loose.move_to(Beam(np.zeros(3), np.array([0.0, 0.0, -1.0])))
    assert sorted(loose.grab()) == ["cam0", "cam1", "cam2"]


def test_replay_runs_out_of_frames(recorded):
    replay = ReplayRig(recorded[0], strict=False)
    n = len(ScanStore.open(recorded[0]).state.frames)
    beam = Beam(np.zeros(3), np.array([0.0, 0.0, -1.0]))
    for _ in range(n):
        replay.move_to(beam)
    with pytest.raises(RigError, match=rf"replay: the recording holds {n} frames; frame {n} was asked for"):
        replay.move_to(beam)


def _video(path, levels, size=(64, 48)):
    import cv2

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, size, True)
    for level in levels:
        writer.write(np.full((size[1], size[0], 3), level, np.uint8))
    writer.release()
    return str(path)


def test_video_capture_cameras_grab_in_step(tmp_path):
    levels = [20, 60, 100, 140]
    cams = VideoCaptureCameras({"left": _video(tmp_path / "l.avi", levels),
                                "right": _video(tmp_path / "r.avi", [255 - x for x in levels])})
    assert isinstance(cams, Cameras) and cams.names == ["left", "right"]
    for level in levels:
        frame = cams.grab()
        assert frame["left"].shape == (48, 64) and frame["left"].dtype == np.uint8
        assert abs(frame["left"].mean() - level) < MJPG_DN_TOL
        assert abs(frame["right"].mean() - (255 - level)) < MJPG_DN_TOL
    with pytest.raises(RigError, match=r"camera 'left' delivered no frame \(disconnected or end of stream\)"):
        cams.grab()
    cams.close()


def test_video_capture_colour_and_bad_source(tmp_path):
    cams = VideoCaptureCameras({"c": _video(tmp_path / "c.avi", [90])}, colour=True)
    assert cams.grab()["c"].shape == (48, 64, 3)
    cams.close()
    with pytest.raises(InputError, match=r"camera 'x': cannot open video source '.*missing.avi'"):
        VideoCaptureCameras({"x": str(tmp_path / "missing.avi")})
