"""Benchmark of issue 10 (reliability): peak memory of ``scanrig detect`` against frame count.

Run: ``python benchmarks/bench_reliability.py [--quick] [--frames 2000]``

A session of one camera with N frames of 1280x1024 8-bit grey (a few distinct noisy spot frames,
hard-linked under N names: the detector reads every file, the disk holds only the distinct ones)
is processed by ``scanrig detect`` in a child process; its peak resident memory
(``getrusage(RUSAGE_CHILDREN).ru_maxrss`` of a wrapper that runs only that child) is printed
against the 1 GB limit of the acceptance, for N = 100 (the baseline), 300 and the full count.
Bounded memory means the peak does not grow with N: the table gives the ratio to N = 100 and the
growth per frame (one frame is 1.25 MiB; keeping the frames would add that much per frame).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

LIMIT_MIB = 1024.0
WIDTH, HEIGHT = 1280, 1024
N_DISTINCT = 8


def make_session(root: Path, n_frames: int, width: int = WIDTH, height: int = HEIGHT, seed: int = 0) -> Path:
    """``root/scan/cam0/00000.png ...``: ``N_DISTINCT`` distinct noisy frames with a Gaussian spot each,
    hard-linked (or copied) under ``n_frames`` names."""
    from scanrig.io.session import write_image

    rng = np.random.default_rng(seed)
    folder = root / "scan" / "cam0"
    folder.mkdir(parents=True)
    distinct = []
    v, u = np.mgrid[:height, :width]
    for k in range(min(N_DISTINCT, n_frames)):
        u0, v0 = rng.uniform(50, width - 50), rng.uniform(50, height - 50)
        img = 12 + 200 * np.exp(-((u - u0) ** 2 + (v - v0) ** 2) / (2 * 2.0**2)) + rng.normal(0, 2, (height, width))
        path = root / f"distinct_{k}.png"
        write_image(path, np.clip(img, 0, 255).astype(np.uint8))
        distinct.append(path)
    for i in range(n_frames):
        target = folder / f"{i:05d}.png"
        try:
            os.link(distinct[i % len(distinct)], target)
        except OSError:
            target.write_bytes(distinct[i % len(distinct)].read_bytes())
    return root


_WRAPPER = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
            "sys.stderr.write(r.stderr); print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")


def detect_peak_rss_mib(session: Path, workers: int = 1) -> tuple[float, float]:
    """Run ``scanrig detect SESSION`` in a fresh child; returns (peak RSS in MiB, seconds)."""
    start = time.perf_counter()
    cmd = [sys.executable, "-c", _WRAPPER, sys.executable, "-m", "scanrig", "detect", str(session),
           "--mode", "spot", "--workers", str(workers)]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    status, max_rss_kib = out.stdout.split()[-2:]
    if status != "0":
        raise RuntimeError(f"scanrig detect failed ({status}): {out.stderr}")
    return int(max_rss_kib) / 1024.0, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="300 frames at most (under a minute).")
    parser.add_argument("--frames", type=int, default=2000, help="Frame count of the full run.")
    args = parser.parse_args()
    counts = [100, 300] + ([] if args.quick else [args.frames])
    print(f"scanrig detect, one camera, {WIDTH}x{HEIGHT} 8-bit frames; peak RSS of the child process "
          f"(measured under load: other jobs share the machine)")
    print(f"{'frames':>7} {'peak RSS MiB':>13} {'x N=100':>8} {'MiB/frame vs 100':>17} {'limit MiB':>10} "
          f"{'verdict':>8} {'time s':>7}")
    base = None
    with tempfile.TemporaryDirectory() as tmp:
        for n in counts:
            session = make_session(Path(tmp) / f"s{n}", n)
            rss, seconds = detect_peak_rss_mib(session)
            base = base or rss
            growth = (rss - base) / (n - counts[0]) if n != counts[0] else 0.0
            print(f"{n:>7} {rss:>13.1f} {rss / base:>8.2f} {growth:>17.4f} {LIMIT_MIB:>10.0f} "
                  f"{'ok' if rss < LIMIT_MIB else 'OVER':>8} {seconds:>7.1f}")


if __name__ == "__main__":
    main()
