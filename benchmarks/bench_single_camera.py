"""Single-camera line-laser turntable scan, end to end from the CLI, measured against the truth.

Runs, in a temporary folder (or ``--keep DIR``)::

    scanrig simulate S --rig turntable --scene turntable --frames N --shots K --seed SEED
    scanrig calibrate S --light-plane --no-cross-validate --no-plots
    scanrig detect S --k-detect K      (K = --k-detect, default 15, as the figures in the docs)
    scanrig reconstruct S --light-plane S/light_plane.toml --out S/points_calibrated.ply
    scanrig evaluate S/points_calibrated.ply --truth S/truth

and prints the time of each stage, the point count and the distance of the points (object frame)
to the true meshes: RMS, median, 99th percentile, maximum. The same points are then reconstructed
with the simulator's true plane (``truth/light_plane.toml``) to show what the calibrated plane
adds.

Run ``python benchmarks/bench_single_camera.py`` (90 frames, 1280 x 960, a few minutes on 2 cores)
or ``--frames 12`` for a quick run.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from scanrig.reconstruct.evaluate import load_truth_surface
from scanrig.reconstruct.points import read_points

#: Detection threshold of the benchmark (docs/tutorial-real-rig.md: single-camera scans).
K_DETECT = 15


def run(stage: str, args: list[str], timings: dict) -> str:
    """Run one ``scanrig`` verb, record its wall time, return its last output line."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "scanrig", *args], capture_output=True, text=True)
    timings[stage] = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"scanrig {' '.join(args)} failed ({done.returncode}):\n{done.stdout}\n{done.stderr}")
    return done.stdout.strip().splitlines()[-1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=90, help="turntable frames over one turn")
    parser.add_argument("--shots", type=int, default=12, help="calibration shots of the cube")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--keep", type=Path, help="write the session here instead of a temporary folder")
    parser.add_argument("--k-detect", type=float, default=K_DETECT, help="detection threshold, noise sigma")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        session = args.keep or Path(tmp) / "turntable"
        timings: dict[str, float] = {}
        run("simulate", ["simulate", str(session), "--rig", "turntable", "--scene", "turntable",
                         "--frames", str(args.frames), "--shots", str(args.shots), "--seed", str(args.seed)], timings)
        planes = {"calibrated plane": session / "light_plane.toml",
                  "true plane": session / "truth" / "light_plane.toml"}
        print("calibrate:", run("calibrate", ["calibrate", str(session), "--light-plane", "--no-cross-validate",
                                              "--no-plots"], timings))
        print("detect:", run("detect", ["detect", str(session), "--k-detect", str(args.k_detect)], timings))
        truth = load_truth_surface(session / "truth")
        results = {}
        for label, plane in planes.items():
            out = session / f"points_{label.split()[0]}.ply"
            print(f"reconstruct ({label}):", run(f"reconstruct ({label})", [
                "reconstruct", str(session), "--light-plane", str(plane), "--out", str(out)], timings))
            print(f"evaluate ({label}):", run(f"evaluate ({label})", [
                "evaluate", str(out), "--truth", str(session / "truth")], timings))
            cloud, _ = read_points(out)
            results[label] = (1e3 * truth(cloud.p_world), cloud.sigma)
    print(f"\n{args.frames} frames, {args.shots} calibration shots, seed {args.seed}")
    print("time (s): " + ", ".join(f"{k} {v:.1f}" for k, v in timings.items()))
    for label, (d_mm, sigma_m) in results.items():
        print(f"{label}: {len(d_mm)} points, RMS {np.sqrt(np.mean(d_mm**2)):.4f} mm, median {np.median(d_mm):.4f} mm, "
              f"p99 {np.percentile(d_mm, 99):.4f} mm, max {d_mm.max():.4f} mm, median predicted sigma "
              f"{1e3 * np.median(sigma_m):.4f} mm")


if __name__ == "__main__":
    main()
