"""`scanrig detect` runs in bounded memory: its peak RSS does not grow with the number of frames.

A smaller version of ``benchmarks/bench_reliability.py`` (which checks 2,000 frames of 1280x1024
against 1 GB): 40 and 160 frames of 640x512. If detect kept the frames (or anything per frame of
their size), the 120 extra frames would add at least 120 x 0.3125 MiB = 37.5 MiB to the peak.
"""

import importlib.util
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_reliability.py"
FRAME_MIB = 640 * 512 / 2**20
#: Allowed growth of the peak: a third of what retaining the extra frames would cost.
MAX_GROWTH_MIB = (160 - 40) * FRAME_MIB / 3


def _bench():
    spec = importlib.util.spec_from_file_location("bench_reliability", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_detect_peak_memory_does_not_grow_with_frames(tmp_path):
    bench = _bench()
    peaks = {}
    for n in (40, 160):
        session = bench.make_session(tmp_path / f"s{n}", n, width=640, height=512, seed=n)
        peaks[n], _ = bench.detect_peak_rss_mib(session)
    assert peaks[160] - peaks[40] < MAX_GROWTH_MIB, peaks
    assert peaks[160] < bench.LIMIT_MIB
