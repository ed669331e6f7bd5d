"""A laser-off frame from the scan itself (``scanrig detect --dark median``) against none and a real one.

Over-exposed red stripes (crosstalk, halo, Bayer, JPEG 4:2:0) swept evenly across printed paper
in N frames (``tests/laser/colour_synth.stripe_sweep``, 480 x 640 px). For each seed and N, the
stripes are detected with no laser-off frame, with the real one, and with the per-pixel median of
the N frames; printed: rank 0 within 0.5 px of the true centre over all rows, the median error
and the candidates per frame.

    python benchmarks/bench_median_dark.py [--seeds 0 1 2] [--frames 5 9 15]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from scanrig.io.session import write_image  # noqa: E402
from scanrig.laser.median_dark import median_dark  # noqa: E402
from scanrig.laser.stripes import detect_stripe  # noqa: E402
from tests.laser.colour_synth import stripe_sweep  # noqa: E402


def _scores(frames, centres, dark):
    """Rank-0 errors on every row (inf where none) and the candidate count, over the frames."""
    errors, n_candidates = [], 0
    for frame, centre_u in zip(frames, centres):
        table = detect_stripe(frame, color="red", dark=dark)
        u, v, line, rank = (table[c].to_numpy() for c in ("u", "v", "line", "rank"))
        best = (rank == 0) & (v == line)
        error = np.full(frame.shape[0], np.inf)
        error[line[best]] = np.abs(u[best] - centre_u[line[best]])
        errors.append(error)
        n_candidates += len(table)
    return np.concatenate(errors), n_candidates


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--frames", type=int, nargs="+", default=[5, 9, 15])
    args = parser.parse_args(argv)
    print("frames  laser-off frame  rank 0 within 0.5 px  median error px  candidates/frame")
    for n_frames in args.frames:
        pooled = {"none": ([], 0), "real": ([], 0), "median": ([], 0)}
        for seed in args.seeds:
            frames, off, centres = stripe_sweep(np.random.default_rng(seed), n_frames)
            with tempfile.TemporaryDirectory() as tmp:   # as `scanrig detect` reads them: from files
                paths = [Path(tmp) / f"f{k:02d}.png" for k in range(n_frames)]
                for path, frame in zip(paths, frames):
                    write_image(path, frame)
                median = median_dark(paths, "cam0")
            for name, dark in (("none", None), ("real", off), ("median", median)):
                errors, n = _scores(frames, centres, dark)
                pooled[name] = (pooled[name][0] + [errors], pooled[name][1] + n)
        for name, (errors, n) in pooled.items():
            e = np.concatenate(errors)
            print(f"{n_frames:6d}  {name:15s}  {np.mean(e < 0.5):20.3f}  {np.median(e[np.isfinite(e)]):15.3f}  "
                  f"{n / (n_frames * len(args.seeds)):16.0f}")


if __name__ == "__main__":
    main()
