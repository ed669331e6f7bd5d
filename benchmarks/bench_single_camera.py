"""Single-camera line-laser turntable scan, end to end from the CLI, measured against the truth.

Runs, in a temporary folder (or ``--keep DIR``)::

    scanrig simulate S --rig turntable --scene turntable --frames N --shots K --seed SEED
    scanrig calibrate S --no-cross-validate --no-plots
    scanrig detect S --k-detect 15
    scanrig reconstruct S --light-plane S/truth/light_plane.toml
    scanrig evaluate S/points.ply --truth S/truth

and prints the time of each stage, the point count and the distance of the points (object frame)
to the true meshes: RMS, median, 99th percentile, maximum. The light plane is the simulator's
true plane (``truth/light_plane.toml``): the camera is calibrated, the plane is not, so the
figures measure the camera calibration, the stripe detection and the turntable mapping.

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
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        session = args.keep or Path(tmp) / "turntable"
        timings: dict[str, float] = {}
        run("simulate", ["simulate", str(session), "--rig", "turntable", "--scene", "turntable",
                         "--frames", str(args.frames), "--shots", str(args.shots), "--seed", str(args.seed)], timings)
        print("calibrate:", run("calibrate", ["calibrate", str(session), "--no-cross-validate", "--no-plots"],
                                timings))
        print("detect:", run("detect", ["detect", str(session), "--k-detect", str(K_DETECT)], timings))
        print("reconstruct:", run("reconstruct", ["reconstruct", str(session), "--light-plane",
                                                  str(session / "truth" / "light_plane.toml")], timings))
        print("evaluate:", run("evaluate", ["evaluate", str(session / "points.ply"), "--truth",
                                            str(session / "truth")], timings))
        cloud, _ = read_points(session / "points.ply")
        d_mm = 1e3 * load_truth_surface(session / "truth")(cloud.p_world)
    print(f"\n{args.frames} frames, {args.shots} calibration shots, seed {args.seed}")
    print("time (s): " + ", ".join(f"{k} {v:.1f}" for k, v in timings.items())
          + f"; pipeline after simulate {sum(v for k, v in timings.items() if k != 'simulate'):.1f}")
    print(f"points {len(d_mm)}: RMS {np.sqrt(np.mean(d_mm**2)):.4f} mm, median {np.median(d_mm):.4f} mm, "
          f"p99 {np.percentile(d_mm, 99):.4f} mm, max {d_mm.max():.4f} mm, median predicted sigma "
          f"{1e3 * np.median(cloud.sigma):.4f} mm")


if __name__ == "__main__":
    main()
