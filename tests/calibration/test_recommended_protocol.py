"""The recommended calibration target of docs/calibration.md is valid and is the benchmarked one."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import numpy as np

from scanrig.targets import load_target

ROOT = Path(__file__).resolve().parents[2]


def _recommended_toml() -> str:
    text = (ROOT / "docs" / "calibration.md").read_text()
    section = text.split("## Recommended protocol", 1)[1].split("\n## ", 1)[0]
    return re.search(r"^```toml\n(.*?)^```", section, re.DOTALL | re.MULTILINE).group(1)


def test_documented_target_loads_with_distinct_ids(tmp_path):
    path = tmp_path / "target.toml"
    path.write_text(_recommended_toml())
    target = load_target(path)
    assert target.kind == "cube" and len(target.boards) == 6
    assert all(len(b.point_ids) == 13 * 13 for b in target.boards)
    assert len(np.unique(target.point_ids)) == len(target.point_ids)
    # Marker ids of the six faces are disjoint and fit the 1000-marker dictionary.
    first = [b.first_marker_id for b in target.boards]
    n = target.boards[0].n_markers
    assert n == 14 * 14 // 2 and first == [k * n for k in range(6)] and first[-1] + n <= 1000


def test_documented_target_is_the_benchmarked_protocol(tmp_path):
    spec = importlib.util.spec_from_file_location("bench_calibration", ROOT / "benchmarks" / "bench_calibration.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    path = tmp_path / "target.toml"
    path.write_text(_recommended_toml())
    documented = load_target(path).spec
    for key in ("edge_m", "squares", "square_m", "marker_m"):
        assert documented[key] == bench.PROTOCOL[key], key
