"""Two demo runs with one seed write the same files, whatever the thread count and the workers.

The runs are the test session's two quick demos (``tests/quick_demo.py``), each in a process of
its own: the demo's help example with two workers and two threads per library, and the same with
one worker and one thread. Every stage is compared: the rendered images through the detected
corners, the calibration, the traces, the cloud, the filtered surface and its mesh.
"""

from __future__ import annotations

import pytest

from tests.quick_demo import DEMO_TIMEOUT_S

#: Files compared byte for byte (rig.toml without the lines that say when it was written, the
#: PLY files without the comment naming their rig.toml's path).
FILES = ("calibration_report/corners.csv", "traces.parquet", "points.ply", "surface.ply", "mesh.ply")
#: Starts of the rig.toml lines that record when it was written.
DATE_LINES = ("date = ", "# written by")


def _without_lines(text: str, starts: tuple[str, ...]) -> str:
    return "\n".join(line for line in text.splitlines() if not line.startswith(starts))


def _ply_without_rig_path(path) -> bytes:
    """A PLY file's bytes without the header comment that names its session's rig.toml (the
    folders of the two runs differ)."""
    data = path.read_bytes()
    end = data.index(b"end_header\n")
    header = [line for line in data[:end].split(b"\n") if not line.startswith(b"comment rig: ")]
    return b"\n".join(header) + data[end:]


@pytest.mark.slow
@pytest.mark.timeout(DEMO_TIMEOUT_S)
def test_same_seed_same_files_with_one_or_two_threads_and_workers(quick_demo):
    one, two = quick_demo.one_thread, quick_demo.example
    one.check()
    two.check()
    assert "--workers 1" in one.command and "--workers" not in two.command   # the default: 2
    one, two = one.out, two.out
    assert (one / "points.ply").stat().st_size > 1000
    assert _without_lines((one / "rig.toml").read_text(), DATE_LINES) == \
        _without_lines((two / "rig.toml").read_text(), DATE_LINES)
    for name in FILES:
        if name.endswith(".ply"):
            assert _ply_without_rig_path(one / name) == _ply_without_rig_path(two / name), name
        else:
            assert (one / name).read_bytes() == (two / name).read_bytes(), name
