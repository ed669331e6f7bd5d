"""Benchmark of ``scanrig demo``: the time of each stage, with the figures of the run.

Run: ``python benchmarks/bench_demo.py [--quick] [--mode stripe|spot] [--out DIR] [--seed N]``

Prints, per stage, the wall time and the CPU time of this process and its (reaped) worker
processes, then the demo's figures (points, RMS distance to the truth before and after the
filter, the count it removed, coverage) and the load average before and after. On a machine
shared with other work the wall time is inflated by the load; the CPU time is not, and on 2 idle
cores the wall time of a stage is between its CPU time / 2 (both workers busy) and its CPU time.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
from pathlib import Path

from scanrig.demo import run_demo


def cpu_s() -> float:
    """User + system CPU seconds of this process and of its waited-for children."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the test-sized run")
    parser.add_argument("--mode", default="stripe", choices=("stripe", "spot"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, help="session folder (default: a new temporary folder)")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_demo_")) / "demo"
    cpu_at_start: dict[str, float] = {}

    def progress(stage: str, done: int, total: int | None) -> None:
        cpu_at_start.setdefault(stage, cpu_s())

    load_before = Path("/proc/loadavg").read_text().split()[:3]
    start_cpu = cpu_s()
    summary = run_demo(out, mode=args.mode, seed=args.seed, quick=args.quick, workers=args.workers, progress=progress)
    end_cpu = cpu_s()
    load_after = Path("/proc/loadavg").read_text().split()[:3]
    names = [s.name for s in summary.stages]
    print(f"scanrig demo {'--quick ' if args.quick else ''}--mode {args.mode} --seed {args.seed} "
          f"--workers {args.workers} -> {out}")
    print(f"load average (1, 5, 15 min) before: {' '.join(load_before)}, after: {' '.join(load_after)}")
    print(f"{'stage':22s} {'wall s':>8s} {'CPU s':>8s}  result")
    for i, stage in enumerate(summary.stages):
        following = [cpu_at_start[n] for n in names[i + 1:] if n in cpu_at_start]
        cpu = (following[0] if following else end_cpu) - cpu_at_start[stage.name] if stage.name in cpu_at_start else 0.0
        print(f"{stage.name:22s} {stage.seconds:8.1f} {cpu:8.1f}  {stage.status}: {stage.result}")
    print(f"{'total':22s} {summary.wall_s:8.1f} {end_cpu - start_cpu:8.1f}")
    for name, value in summary.figures():
        print(f"{name}: {value}")


if __name__ == "__main__":
    main()
