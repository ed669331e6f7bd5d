"""Killing `scanrig detect` at 10 random moments and resuming gives the uninterrupted result.

The child (:mod:`tests.reliability.detect_child`) runs the real command line with a checkpoint
after every chunk of 8 frames. Between kills the session must stay consistent: ``traces.parquet``
is absent or readable, lists only finished frames, and holds exactly their rows.
"""

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from scanrig.io.session import write_image
from scanrig.laser.traces import read_traces

REPO = Path(__file__).resolve().parents[2]
N_KILLS = 10
CAMERAS, N_FRAMES, SHAPE = ("cam0", "cam1"), 64, (128, 160)


def spot_frames(root: Path, rng: np.random.Generator) -> None:
    """Noisy 8-bit frames (128, 160) with one Gaussian spot each, at random places."""
    v, u = np.mgrid[: SHAPE[0], : SHAPE[1]]
    for cam in CAMERAS:
        (root / "scan" / cam).mkdir(parents=True)
        for i in range(N_FRAMES):
            u0, v0 = rng.uniform(10, SHAPE[1] - 10), rng.uniform(10, SHAPE[0] - 10)
            img = 12 + 180 * np.exp(-((u - u0) ** 2 + (v - v0) ** 2) / (2 * 1.5**2)) + rng.normal(0, 2, SHAPE)
            write_image(root / "scan" / cam / f"{i:05d}.png", np.clip(img, 0, 255).astype(np.uint8))


def checkpoint_id(path: Path):
    """Changes whenever ``traces.parquet`` is replaced (an atomic write gives it a new inode)."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return st.st_ino, st.st_mtime_ns


def run_child(root: Path, kill: tuple[int, float] | None = None) -> tuple[int, list[float]]:
    """Run the child to the end, or SIGKILL it ``kill = (n, s)``: ``s`` seconds after its ``n``-th
    new checkpoint (``n = 0``: after the start). Returns the exit status and the times of the
    checkpoints seen."""
    cmd = [sys.executable, "-m", "tests.reliability.detect_child", str(root)]
    child = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    seen, times = checkpoint_id(root / "traces.parquet"), []
    while child.poll() is None and (kill is None or len(times) < kill[0]):
        now = checkpoint_id(root / "traces.parquet")
        if now != seen:
            seen = now
            times.append(time.monotonic())
        time.sleep(0.002)
    if kill is not None:
        time.sleep(kill[1])
        if child.poll() is None:
            os.kill(child.pid, signal.SIGKILL)
    _, err = child.communicate()
    assert child.returncode in (0, -signal.SIGKILL), err.decode()
    return child.returncode, times


def assert_consistent(root: Path) -> int:
    """``traces.parquet`` is absent or complete for the frames it lists; returns how many it lists."""
    path = root / "traces.parquet"
    if not path.exists():
        return 0
    table, meta = read_traces(path)
    done = {tuple(x) for x in meta["frames_done"]}
    rows = set(zip(table.column("camera").to_pylist(), table.column("frame").to_pylist()))
    assert rows <= done, f"rows of unfinished frames {sorted(rows - done)[:3]}"
    return len(done)


def test_detect_killed_10_times_resumes_to_the_same_traces(tmp_path):
    rng = np.random.default_rng(2024)
    reference = tmp_path / "reference"
    spot_frames(reference, rng)
    killed = shutil.copytree(reference, tmp_path / "killed")

    status, times = run_child(reference)
    assert status == 0 and len(times) >= 2
    chunk_s = (times[-1] - times[0]) / (len(times) - 1)
    expected, expected_meta = read_traces(reference / "traces.parquet")
    assert len(expected_meta["frames_done"]) == len(CAMERAS) * N_FRAMES

    # 16 chunks of 8 frames; each kill lands at most about one chunk after 0 or 1 new checkpoints, so
    # all 10 land mid-run: in the start-up (imports, reading traces.parquet), inside a chunk, or
    # inside a checkpoint write.
    progress = []
    for _ in range(N_KILLS):
        kill = (int(rng.integers(0, 2)), rng.uniform(0.0, 1.0) * chunk_s)
        assert run_child(killed, kill)[0] == -signal.SIGKILL
        progress.append(assert_consistent(killed))
    assert progress == sorted(progress), f"a resumed run lost finished frames: {progress}"
    assert 0 < progress[-1] < len(CAMERAS) * N_FRAMES, progress
    assert run_child(killed)[0] == 0
    table, meta = read_traces(killed / "traces.parquet")
    assert table.equals(expected)
    assert meta == expected_meta


def test_scan_killed_10_times_resumes_to_the_same_points(tmp_path):
    """The stand-in scan of ``tests/scan`` (fake rig, real store and loop), SIGKILLed 10 times, each
    one manifest record further plus up to 30 ms (anywhere inside the next frame's moves and writes;
    31 records in all, so every kill lands mid-scan)."""
    from scanrig.scan.store import ScanStore, read_state
    from tests.scan import fakerig

    rng = np.random.default_rng(77)
    cmd = [sys.executable, "-m", "tests.scan.scan_child"]
    reference, killed = tmp_path / "reference", tmp_path / "killed"
    reference.mkdir()
    subprocess.run(cmd + [str(reference)], cwd=REPO, check=True, capture_output=True)
    manifest = killed / "scan" / "manifest.jsonl"
    frames_done = []
    for attempt in range(N_KILLS):
        start = manifest.read_bytes().count(b"\n") if manifest.exists() else 0
        kill_at = start + 1
        child = subprocess.Popen(cmd + [str(killed)] + (["--resume"] if attempt else []), cwd=REPO,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        while child.poll() is None and (not manifest.exists() or manifest.read_bytes().count(b"\n") < kill_at):
            time.sleep(0.002)
        time.sleep(rng.uniform(0.0, 0.03))
        assert child.poll() is None, "the scan finished before its kill"
        os.kill(child.pid, signal.SIGKILL)
        _, err = child.communicate()
        assert child.returncode == -signal.SIGKILL, err.decode()
        frames_done.append(len(read_state(killed).frames))
    assert frames_done == sorted(frames_done), f"a resumed scan lost frames: {frames_done}"
    done = subprocess.run(cmd + [str(killed), "--resume"], cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    np.testing.assert_array_equal(np.load(killed / "points.npy"), np.load(reference / "points.npy"))
    frames = ScanStore.open(killed).state.frames
    assert frames == ScanStore.open(reference).state.frames
    for cam in fakerig.make_rig().names:
        assert sorted(p.name for p in (killed / "scan" / cam).iterdir()) == ["dark.png"] + [f"{s}.png" for s in frames]


def test_detect_ctrl_c_exits_130_and_leaves_a_consistent_session(tmp_path):
    """SIGINT (Ctrl-C) after the first checkpoint: exit 130, no traceback, a readable partial traces file."""
    spot_frames(tmp_path, np.random.default_rng(9))
    child = subprocess.Popen([sys.executable, "-m", "tests.reliability.detect_child", str(tmp_path)], cwd=REPO,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             env={**os.environ, "SCANRIG_TEST_HOLD": "1"})
    while child.poll() is None and checkpoint_id(tmp_path / "traces.parquet") is None:
        time.sleep(0.002)
    child.send_signal(signal.SIGINT)
    _, err = child.communicate()
    assert child.returncode == 130, err
    assert "Traceback" not in err     # typer turns KeyboardInterrupt into a silent exit 130
    assert 0 < assert_consistent(tmp_path) < len(CAMERAS) * N_FRAMES
