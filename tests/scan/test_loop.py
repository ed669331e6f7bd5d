"""The scan loop against the stand-in rig: completion, and clean stops that resume losslessly."""

import errno
import numpy as np
import pytest

from tests.scan import fakerig
from scanrig.scan import store as store_module
from scanrig.scan.loop import run_scan
from scanrig.scan.processing import SpotProcessor
from scanrig.scan.protocol import RigError
from scanrig.scan.store import ScanStore, StoreError

SEED = 20261123
BUDGET = 24
CONFIG = fakerig.planner_config(spacing_m=0.01, uniform_spacing_m=0.03, max_beams_per_pass=5)


def _scan(root, rig=None, resume=False, **kw):
    rig = rig or fakerig.FakeRig(seed=1)
    store = ScanStore.open(root) if resume else ScanStore.create(root, rig.names, {"seed": SEED})
    process = SpotProcessor(rig.rig, dark=store.dark_paths())
    return run_scan(store, rig, rig, CONFIG, process, np.random.default_rng(SEED), BUDGET, **kw)


def _xyz(result):
    return result.points.p_world


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    root = tmp_path_factory.mktemp("reference")
    return root, _scan(root)


def test_scan_runs_adaptive_passes_within_budget(reference):
    root, result = reference
    store = ScanStore.open(root)
    assert result.n_passes >= 3                      # uniform pass + at least two adaptive ones
    assert len(store.state.frames) <= BUDGET
    assert store.state.finished == result.reason
    assert [f.index for f in result.frames] == list(range(len(store.state.frames)))
    later = [b for p in store.state.passes[1:] for b in p.beams]
    assert any(not np.allclose(b.origin, CONFIG.stations_m[0]) for b in later)   # side stations used


def test_points_lie_on_the_roof(reference):
    _, result = reference
    # each point's sigma is propagated from its detections' covariance (the injected image
    # noise); 5 sigma along the covariance's largest axis bounds the distance to the true surface
    assert len(result.points) >= 10
    assert np.all(fakerig.distance_to_roof(_xyz(result)) <= 5 * result.points.sigma)


def test_resume_of_a_finished_scan_changes_nothing(reference, tmp_path):
    root, result = reference
    again = _scan(root, resume=True)
    np.testing.assert_array_equal(_xyz(again), _xyz(result))
    assert again.reason == result.reason


def test_positioner_error_stops_cleanly_and_resumes_losslessly(reference, tmp_path):
    with pytest.raises(RigError, match=r"the positioner failed moving to f000009: RuntimeError: error:9 \(G-code lock\); "
                                       r"everything captured so far is saved"):
        _scan(tmp_path, fakerig.FakeRig(seed=1, fail_move_at=9))
    assert ScanStore.open(tmp_path).state.frames[-1] == "f000008"
    np.testing.assert_array_equal(_xyz(_scan(tmp_path, resume=True)), _xyz(reference[1]))


def test_camera_that_stops_delivering(reference, tmp_path):
    with pytest.raises(RigError, match=r"camera 'cam1' delivered no valid image for f000005 \(got NoneType\)"):
        _scan(tmp_path, fakerig.FakeRig(seed=1, camera_dies_at=6))       # grab 0 is the dark frame
    np.testing.assert_array_equal(_xyz(_scan(tmp_path, resume=True)), _xyz(reference[1]))


def test_camera_that_hangs(tmp_path):
    with pytest.raises(RigError, match=r"the cameras delivered no frame for f000002 within 1 s"):
        _scan(tmp_path, fakerig.FakeRig(seed=1, camera_dies_at=3, hang=True), grab_timeout_s=1.0)
    assert ScanStore.open(tmp_path).state.frames == ["f000000", "f000001"]


def test_full_disk_while_writing(reference, tmp_path, monkeypatch):
    real_write = store_module.write_image
    calls = {"n": 0}

    def write_until_full(path, image):
        calls["n"] += 1
        if calls["n"] == 3 * (1 + 7) + 3:           # dark frame, frames 0-6, third camera of frame 7
            raise OSError(errno.ENOSPC, "No space left on device")
        real_write(path, image)

    monkeypatch.setattr(store_module, "write_image", write_until_full)
    with pytest.raises(StoreError, match=r"cannot write frame f000007 of camera 'cam2': \[Errno 28\] No space left on device; "
                                         r"everything captured so far is saved"):
        _scan(tmp_path)
    monkeypatch.setattr(store_module, "write_image", real_write)
    assert ScanStore.open(tmp_path).state.frames[-1] == "f000006"
    np.testing.assert_array_equal(_xyz(_scan(tmp_path, resume=True)), _xyz(reference[1]))


def test_rig_with_other_cameras_is_refused(reference):
    root, _ = reference
    rig = fakerig.FakeRig(seed=1)
    rig.names = ["cam0", "cam1"]
    with pytest.raises(RigError, match=r"the rig's cameras \['cam0', 'cam1'\] differ from the scan's \['cam0', 'cam1', 'cam2'\]"):
        _scan(root, rig, resume=True)


def test_killed_scan_resumes_to_the_same_points(reference, tmp_path):
    """SIGKILL at random moments (twice), resume each time: same points, no frame lost or duplicated."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    rng = np.random.default_rng(31)
    repo = Path(__file__).resolve().parents[2]
    manifest = tmp_path / "scan" / "manifest.jsonl"
    cmd = [sys.executable, "-m", "tests.scan.scan_child", str(tmp_path)]
    n_kills = 0
    for attempt in range(2):
        kill_after_lines = int(rng.integers(3, 12)) + 12 * attempt    # log records: start, passes, frames
        child = subprocess.Popen(cmd + (["--resume"] if attempt else []), cwd=repo, stderr=subprocess.PIPE)
        while child.poll() is None and (not manifest.exists() or manifest.read_bytes().count(b"\n") < kill_after_lines):
            time.sleep(0.005)
        time.sleep(rng.uniform(0.0, 0.03))                   # anywhere inside the next frame
        if child.poll() is None:
            os.kill(child.pid, signal.SIGKILL)
            n_kills += 1
        _, err = child.communicate()
        assert child.returncode in (0, -signal.SIGKILL), err.decode()
    assert n_kills >= 1
    done = subprocess.run(cmd + ["--resume"], cwd=repo, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    np.testing.assert_array_equal(np.load(tmp_path / "points.npy"), _xyz(reference[1]))
    frames = ScanStore.open(tmp_path).state.frames
    assert frames == ScanStore.open(reference[0]).state.frames
    for cam in fakerig.make_rig().names:
        assert sorted(p.name for p in (tmp_path / "scan" / cam).iterdir()) == ["dark.png"] + [f"{s}.png" for s in frames]
