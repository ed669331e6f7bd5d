"""Benchmark of issue 7 (scanning): adaptive vs uniform beams, kill/resume, Dask vs local pool.

Run: ``python benchmarks/bench_scan.py [--quick]``

A. Planner on a truncated pyramid with 72-degree faces (geometric rig: beams are ray-cast, points
   kept when two cameras see them, 0.1 mm noise): the adaptive loop versus uniform grids from the
   top station refined until they reach the same coverage. Coverage = fraction of the visible
   surface whose local spacing is within 1.5x the target spacing (``scanrig.scan.coverage``).
B. ``scanrig scan`` on the simulator (small sphere scene, quarter-size cameras) killed with
   SIGKILL at a random moment and resumed, against an uninterrupted run with the same seed.
C. Processing the frames of run B on a local process pool and on a Dask ``LocalCluster`` (same
   number of workers): identical points, throughput per worker.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))          # the geometric rig lives with the tests (tests/scan/geometric.py)

from scanrig.scan.coverage import COVERED_FACTOR, coverage_fraction, local_spacing  # noqa: E402
from tests.scan import geometric  # noqa: E402

SCENE = REPO / "tests" / "scan" / "data" / "small_sphere.toml"
TARGET_COVERAGE = 0.95


def coverage_map(samples, points, spacing_m, cells=24) -> list[str]:
    """Top view of the surface samples: per cell '#' >= 95 % covered, '+' >= 80 %, '.' below, ' ' empty."""
    ok = local_spacing(samples, points) <= COVERED_FACTOR * spacing_m
    lo, hi = samples[:, :2].min(axis=0), samples[:, :2].max(axis=0)
    ij = np.minimum(((samples[:, :2] - lo) / (hi - lo) * cells).astype(int), cells - 1)
    flat = ij[:, 1] * cells + ij[:, 0]
    n = np.bincount(flat, minlength=cells * cells)
    good = np.bincount(flat, weights=ok, minlength=cells * cells)
    frac = np.where(n > 0, good / np.maximum(n, 1), np.nan).reshape(cells, cells)[::-1]
    return ["".join(" " if np.isnan(f) else "#" if f >= 0.95 else "+" if f >= 0.8 else "." for f in row) for row in frac]


def face_table(samples, normal, points, spacing_m) -> dict[str, float]:
    """Coverage per face group of the pyramid: top and the four steep sides."""
    ok = local_spacing(samples, points) <= COVERED_FACTOR * spacing_m
    names = np.where(normal[:, 2] > 0.9, "top", np.where(np.abs(normal[:, 0]) > np.abs(normal[:, 1]),
                                                          np.where(normal[:, 0] > 0, "+x side", "-x side"),
                                                          np.where(normal[:, 1] > 0, "+y side", "-y side")))
    return {name: float(ok[names == name].mean()) for name in ("top", "+x side", "-x side", "+y side", "-y side")}


def part_a(quick: bool) -> None:
    spacing = 0.006 if quick else 0.004
    rig = geometric.GeometricRig()
    config = geometric.planner_config(spacing_m=spacing, uniform_spacing_m=1.5 * spacing, max_passes=15)
    samples, normals = rig.visible_surface(config, 20000 if quick else 60000, np.random.default_rng(1))
    t0 = time.perf_counter()
    points, per_pass = geometric.adaptive_scan(rig, config, 20000, np.random.default_rng(2))
    t_adaptive = time.perf_counter() - t0
    adaptive = coverage_fraction(samples, points, spacing)
    grid, uniform, n_uniform, at_target = spacing, 0.0, 0, None
    while uniform < adaptive:
        grid *= 0.95
        upoints, n_uniform = geometric.uniform_scan(rig, config, grid, np.random.default_rng(3))
        uniform = coverage_fraction(samples, upoints, spacing)
        if at_target is None and uniform >= TARGET_COVERAGE:
            at_target = (grid, n_uniform, uniform)
    same_grid = _grid_for(config, sum(per_pass))
    same_points, n_same = geometric.uniform_scan(rig, config, same_grid, np.random.default_rng(4))
    same = coverage_fraction(samples, same_points, spacing)
    print(f"\nA. planner on a pyramid with 72-degree faces, target spacing {spacing * 1e3:.1f} mm, "
          f"{len(samples)} visible-surface samples")
    print(f"{'method':<46}{'beams':>8}{'coverage':>10}{'beams vs adaptive':>19}")
    rows = [(f"adaptive ({len(per_pass)} passes)", sum(per_pass), adaptive),
            (f"uniform {same_grid * 1e3:.2f} mm grid, same beam count", n_same, same),
            (f"uniform {grid * 1e3:.2f} mm grid, same coverage (baseline)", n_uniform, uniform)]
    if at_target is not None:
        rows.insert(2, (f"uniform {at_target[0] * 1e3:.2f} mm grid, first to reach 95 %", *at_target[1:]))
    for name, n, cov in rows:
        print(f"{name:<46}{n:>8}{cov:>10.3f}{n / sum(per_pass):>19.2f}")
    print(f"acceptance: adaptive coverage {adaptive:.3f} >= {TARGET_COVERAGE}: {adaptive >= TARGET_COVERAGE}; "
          f"fewer beams than the uniform baseline: {sum(per_pass) < n_uniform}")
    print(f"beams per pass {per_pass}; planning + ray casting {t_adaptive:.1f} s")
    print("coverage per face (adaptive / uniform with the same beam count):")
    for (face, a), u in zip(face_table(samples, normals, points, spacing).items(),
                            face_table(samples, normals, same_points, spacing).values()):
        print(f"  {face:<8} {a:.3f} / {u:.3f}")
    print("coverage maps, top view ('#' >= 95 %, '+' >= 80 %, '.' below); left adaptive, right uniform with "
          "the same beam count:")
    for a, u in zip(coverage_map(samples, points, spacing), coverage_map(samples, same_points, spacing)):
        print(f"  |{a}|   |{u}|")


def _grid_for(config, n_beams: int) -> float:
    """Uniform grid spacing whose beam count is closest to ``n_beams``."""
    from scanrig.scan.planner import uniform_aims

    grid = config.spacing_m
    while len(uniform_aims(config, grid)) < n_beams:
        grid *= 0.98
    return grid


def _scan_cmd(root: Path, budget: int, resume: bool = False) -> list[str]:
    cmd = [str(Path(sys.executable).parent / "scanrig"), "scan", str(root), "--sim", str(SCENE), "--sim-scale", "0.25",
           "--roi-mm=-70,-70,5,70,70,130", "--workers", "1"]
    return cmd + (["--resume"] if resume else ["--budget", str(budget), "--spacing-mm", "12", "--seed", "5"])


def part_b(quick: bool, work: Path) -> Path:
    from scanrig.reconstruct.points import read_points
    from scanrig.scan.store import read_state

    budget = 40 if quick else 80
    ref, killed = work / "reference", work / "killed"
    t0 = time.perf_counter()
    subprocess.run(_scan_cmd(ref, budget), check=True, capture_output=True)
    t_ref = time.perf_counter() - t0
    rng = np.random.default_rng(11)
    kill_at = int(rng.integers(2, budget - 2))
    child = subprocess.Popen(_scan_cmd(killed, budget), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    manifest = killed / "scan" / "manifest.jsonl"
    while child.poll() is None and (not manifest.exists() or manifest.read_bytes().count(b'"kind":"frame"') < kill_at):
        time.sleep(0.01)
    time.sleep(rng.uniform(0, 0.3))
    was_running = child.poll() is None
    if was_running:
        os.kill(child.pid, signal.SIGKILL)
    child.wait()
    n_before = len(read_state(killed).frames)
    subprocess.run(_scan_cmd(killed, budget, resume=True), check=True, capture_output=True)
    a, b = read_points(ref / "points.ply")[0], read_points(killed / "points.ply")[0]
    fa, fb = read_state(ref).frames, read_state(killed).frames
    files_ok = all(sorted(p.stem for p in (killed / "scan" / c).glob("*.png")) == sorted(fb + ["dark"])
                   for c in read_state(killed).cameras)
    print(f"\nB. scanrig scan --sim (small sphere, budget {budget}) killed after frame {n_before - 1} "
          f"(SIGKILL {'mid-scan' if was_running else 'too late: scan had finished'}), then --resume")
    print(f"uninterrupted: {len(fa)} frames in {len(read_state(ref).passes)} passes ({read_state(ref).finished}), "
          f"{len(a)} points, {t_ref:.1f} s;  killed+resumed: {len(fb)} frames, {len(b)} points")
    same = len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a.vertex_fields().values(), b.vertex_fields().values()))
    print(f"acceptance: identical point set (every field, bit for bit): {same}; same frame list: {fa == fb}; "
          f"no frame lost or duplicated on disk: {files_ok}")
    return ref


def part_c(session: Path, workers: int) -> None:
    from distributed import Client, LocalCluster

    from scanrig.io.rig_file import load_rig
    from scanrig.scan.processing import (DaskExecutor, LocalPoolExecutor, SerialExecutor, SpotProcessor,
                                         concat_points, frame_jobs, process_frames)
    from scanrig.scan.store import ScanStore

    store = ScanStore.open(session)
    jobs = frame_jobs(store.frame_paths())
    process = SpotProcessor(load_rig(session / "rig.toml"), color="red", dark=store.dark_paths())
    rows = []
    for name, make in (("serial (this process)", SerialExecutor),
                       (f"local pool, {workers} workers", lambda: LocalPoolExecutor(workers))):
        with make() as ex:
            process_frames(ex, process, jobs[:workers])                         # warm up the workers
            t0 = time.perf_counter()
            out = process_frames(ex, process, jobs)
            rows.append((name, time.perf_counter() - t0, out, 1 if name.startswith("serial") else workers))
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client, DaskExecutor(client) as ex:
        process_frames(ex, process, jobs[:workers])
        t0 = time.perf_counter()
        out = process_frames(ex, process, jobs)
        rows.append((f"Dask LocalCluster, {workers} workers", time.perf_counter() - t0, out, workers))
    base = concat_points(rows[0][2]).vertex_fields()
    print(f"\nC. processing the {len(jobs)} frames of run B (detect + match + triangulate per frame)")
    print(f"{'executor':<32}{'seconds':>9}{'frames/s':>10}{'per worker':>12}{'vs serial':>11}  identical")
    for name, secs, out, n in rows:
        fields = concat_points(out).vertex_fields()
        same = all(np.array_equal(base[k], fields[k]) for k in base)
        print(f"{name:<32}{secs:>9.2f}{len(jobs) / secs:>10.1f}{len(jobs) / secs / n:>12.1f}"
              f"{rows[0][1] / secs:>11.2f}  {same}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller problems (about a minute on an idle machine)")
    args = parser.parse_args()
    print(f"bench_scan ({'quick' if args.quick else 'full'}); timings measured on this machine, under its current load")
    part_a(args.quick)
    with tempfile.TemporaryDirectory() as tmp:
        session = part_b(args.quick, Path(tmp))
        part_c(session, 2)


if __name__ == "__main__":
    main()
