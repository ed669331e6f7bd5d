"""Board flex benchmark: is a bent board flagged when calibrated as flat, and recovered with ``flex = true``?

Run ``python benchmarks/bench_flex.py`` (5 seeds) or ``--seeds 2`` for a quick look. Simulated
corners (no rendering): two cameras 30 deg apart 0.8 m from the origin (opencv5, f 1400 px,
1280x1024), a ChArUco board of 10 x 7 squares of 50 mm (0.5 m x 0.35 m; ``--small`` for 7 x 5
squares of 40 mm) moved over both fields of view in 16 shots (``--shots``), corners seen up to
70 deg from the board normal while their squares image >= 16 px, 0.1 px noise, the board bent by
``--flex-mm`` (c_x, c_y of :func:`scanrig.targets.target.flex_shape`).

Per seed it prints the cross-validation ratio of each camera with flex off (the board calibrated
as flat; above 3 is warned) and on, whether the flat-board solution warns that the board looks
bent (:mod:`scanrig.calibration.flex_check`), and the flex recovered with ``flex = true`` and its
sigma.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from scanrig.calibration.cross_validation import RATIO_WARN  # noqa: E402
from scanrig.calibration.pipeline import calibrate  # noqa: E402
from scanrig.calibration.synthetic import DETECTABLE_SQUARE_PX, ring_cameras, simulate  # noqa: E402
from scanrig.targets import charuco  # noqa: E402

SIGMA_PX = 0.1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--shots", type=int, default=16)
    parser.add_argument("--flex-mm", default="1.0,0.4", help="c_x,c_y in mm")
    parser.add_argument("--small", action="store_true", help="a 0.28 m x 0.2 m board (7 x 5 squares of 40 mm)")
    args = parser.parse_args()
    flex_m = np.array([float(v) for v in args.flex_mm.split(",")]) * 1e-3
    squares, square_m = ((7, 5), 0.04) if args.small else ((10, 7), 0.05)
    rigid = charuco(squares, square_m, 0.75 * square_m)
    flexible = charuco(squares, square_m, 0.75 * square_m, flex=True)
    with open("/proc/loadavg") as f:
        print(f"load: {f.read().strip()}")
    print(f"board {squares[0]}x{squares[1]} squares of {square_m * 1000:g} mm, {args.shots} shots, "
          f"flex {flex_m * 1000} mm, noise {SIGMA_PX} px")
    print("seed | ratio flex off (warned) | bent-board warning | ratio flex on (warned) | "
          "flex on: c_x, c_y ± sigma (mm) | time off, on")
    errors, off, on, bent_warned = [], [], [], 0
    for seed in range(args.seeds):
        rng = np.random.default_rng(seed)
        cams = ring_cameras(2, rng=rng)
        sim = simulate(cams, rigid, args.shots, SIGMA_PX, rng, cover=True, min_square_px=DETECTABLE_SQUARE_PX,
                       flex_m=flex_m)
        parts, times, results = [], [], []
        for target in (rigid, flexible):
            t0 = time.perf_counter()
            results.append(calibrate(sim.obs, target, "opencv5"))
            times.append(time.perf_counter() - t0)
        for result, store in zip(results, (off, on)):
            cv = result.cross_validation
            if cv is None:
                parts.append("not run")
                continue
            ratios = [r.ratio for r in cv.cameras.values() if r is not None]
            store += ratios
            warned = sum("x their stated sigma" in w for w in result.warnings)
            parts.append(" ".join(f"{r:.2f}" for r in ratios) + f" ({warned})")
        flex, sigma = results[1].bundle.state.flex_m, results[1].uncertainty.flex_std_m
        errors.append((flex - flex_m) / sigma)
        bent = any(w.startswith("target: the board looks bent") for w in results[0].warnings)
        bent_warned += bent
        print(f"{seed:4d} | {parts[0]} | {'yes' if bent else 'no'} | {parts[1]} | "
              f"{flex[0] * 1000:.4f} ± {sigma[0] * 1000:.4f}, "
              f"{flex[1] * 1000:.4f} ± {sigma[1] * 1000:.4f} | {times[0]:.1f}s, {times[1]:.1f}s", flush=True)
    z, off, on = np.array(errors), np.array(off), np.array(on)
    print(f"flex off: ratio median {np.median(off):.2f} [{off.min():.2f}, {off.max():.2f}], "
          f"{np.count_nonzero(off > RATIO_WARN)}/{len(off)} above {RATIO_WARN:g}; bent-board warning in "
          f"{bent_warned}/{args.seeds} sessions")
    print(f"flex on:  ratio median {np.median(on):.2f} [{on.min():.2f}, {on.max():.2f}], "
          f"{np.count_nonzero(on > RATIO_WARN)}/{len(on)} above {RATIO_WARN:g}")
    print(f"flex error / sigma: RMS {np.sqrt(np.mean(z ** 2)):.2f}, largest {np.abs(z).max():.2f}")


if __name__ == "__main__":
    main()
