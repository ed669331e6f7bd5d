"""Report speed: ``write_report`` on a synthetic session against a static matplotlib 3-D scatter.

The baseline is what a report without an interactive viewer would do for its 3-D view: one
matplotlib ``scatter3D`` PNG of the same points. The table gives the time of each and the ratio,
and the size of the HTML. Run: ``python benchmarks/bench_report.py [--quick]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _session(root: Path, n_points: int, rng: np.random.Generator) -> Path:
    import trimesh

    from scanrig.io.atomic import write_bytes_atomic
    from scanrig.reconstruct.points import PointCloud, write_points

    (root / "truth" / "meshes").mkdir(parents=True)
    normals = rng.normal(size=(n_points, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    p = normals * (0.05 + rng.normal(0.0, 1e-4, n_points))[:, None]
    write_points(root / "points.ply", PointCloud(p, np.full(n_points, 1e-4), np.full(n_points, 3),
                                                 np.zeros(n_points), np.zeros(n_points), np.zeros(n_points)))
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.05)
    write_bytes_atomic(root / "truth" / "meshes" / "sphere.ply", sphere.export(file_type="ply"))
    return root


def _baseline(p: np.ndarray) -> float:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from scanrig.report.plots import figure_uri

    start = time.perf_counter()
    fig = plt.figure(figsize=(9, 6))
    ax = fig.add_subplot(projection="3d")
    ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=0.5, c=p[:, 2])
    figure_uri(fig)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20 000 points instead of 200 000")
    args = parser.parse_args()
    n = 20_000 if args.quick else 200_000
    from scanrig.reconstruct.points import read_points
    from scanrig.report import write_report

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = _session(Path(tmp) / "s", n, np.random.default_rng(0))
        start = time.perf_counter()
        out = write_report(root, rng=np.random.default_rng(1))
        t_report = time.perf_counter() - start
        t_base = _baseline(read_points(root / "points.ply")[0].p_world)
        size_mb = out.stat().st_size / 1e6
    rows.append(("write_report (all sections, interactive 3-D view)", t_report, t_report / t_base))
    rows.append(("baseline: matplotlib scatter3D PNG of the cloud only", t_base, 1.0))
    print(f"{n} points; report.html {size_mb:.1f} MB (measured under whatever load the machine has)")
    print(f"{'what':<55} {'time (s)':>9} {'ratio':>7}")
    for name, seconds, ratio in rows:
        print(f"{name:<55} {seconds:9.2f} {ratio:7.2f}")


if __name__ == "__main__":
    main()
