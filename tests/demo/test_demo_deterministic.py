"""Two demo runs with one seed write the same files, whatever the thread count and the workers.

Each run is ``scanrig demo --quick`` in a process of its own (the thread counts of OpenMP,
OpenBLAS, MKL and torch are fixed when a process starts): one with one thread and one worker,
one with two of each. Every stage is compared: the rendered images through the detected corners,
the calibration, the traces, the cloud, the filtered surface and its mesh.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

#: The demo's seed in both runs.
SEED = 3
#: Files compared byte for byte (rig.toml without the lines that say when it was written, the
#: PLY files without the comment naming their rig.toml's path).
FILES = ("calibration_report/corners.csv", "traces.parquet", "points.ply", "surface.ply", "mesh.ply")
#: Starts of the rig.toml lines that record when it was written.
DATE_LINES = ("date = ", "# written by")


def _start(out, threads: int, workers: int) -> subprocess.Popen:
    """``scanrig demo --quick`` in a process of its own with ``threads`` threads per library."""
    env = os.environ | {name: str(threads) for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                        "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")}
    return subprocess.Popen([sys.executable, "-m", "scanrig", "demo", "--out", str(out), "--quick", "--seed",
                             str(SEED), "--workers", str(workers)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


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
def test_same_seed_same_files_with_one_or_two_threads_and_workers(tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    runs = [_start(one, threads=1, workers=1), _start(two, threads=2, workers=2)]
    for run in runs:
        output = run.communicate()[0]
        assert run.returncode == 0, output[-3000:]
    assert (one / "points.ply").stat().st_size > 1000
    assert _without_lines((one / "rig.toml").read_text(), DATE_LINES) == \
        _without_lines((two / "rig.toml").read_text(), DATE_LINES)
    for name in FILES:
        if name.endswith(".ply"):
            assert _ply_without_rig_path(one / name) == _ply_without_rig_path(two / name), name
        else:
            assert (one / name).read_bytes() == (two / name).read_bytes(), name
