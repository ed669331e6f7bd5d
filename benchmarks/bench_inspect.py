"""Inspection against CAD: alignment accuracy, deviation accuracy, bump heights and speed, over seeds.

Synthetic parts (tests/inspect/synth.py): a 60 x 40 x 20 mm bracket with planes and a cylindrical
face, scanned from one side, with Gaussian bumps and dents of 0.1-0.5 mm, 20 um noise, 10 %
outliers and a random rigid motion of up to 30 deg and 50 mm.

Prints, per seed, at 40 000 points: the alignment error (RMS distance between the surface points
mapped by the true and the estimated transform), the deviation error (RMS of measured minus
designed deviation) over the noise sigma, the worst bump-height error, and the time of
``inspect_cloud`` (wall clock, and CPU time of all threads: on a shared machine the CPU time is
the figure that does not depend on the other users' load); then the time of ``inspect_cloud``,
``write_inspection`` and the HTML page for 1 000 000 points. For context, in the same run:
Open3D's plain point-to-plane ICP from the identity (what a fit without coarse alignment or
robust weights gives) on the same 40 000 points against 250 000 CAD samples, its alignment error
and time.

With ``--multistart``, instead: the CPU time of the multi-start coarse search on seed 1's 40 000
points (125 starts), its starts iterated together against the same starts' ICP run one after
the other (the baseline, ``robust_icp`` per start), medians of 3 runs in turn, and the largest
difference between the poses the two pick.

Run: python benchmarks/bench_inspect.py [n_seeds] [--no-million | --multistart]
"""

from __future__ import annotations

import importlib.util
import sys
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def baseline_open3d(scan, mesh, seed: int):
    """Plain Open3D point-to-plane ICP from the identity (no coarse alignment), its error and time."""
    import open3d as o3d

    from tests.inspect import synth

    reg = o3d.pipelines.registration
    t0, c0 = time.perf_counter(), time.process_time()
    cad_points = mesh.sample(250_000, seed=np.random.default_rng(seed))
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cad_points))
    target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2e-3, max_nn=30))
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan.points_m))
    result = reg.registration_icp(source, target, 5e-3, np.eye(4), reg.TransformationEstimationPointToPlane(),
                                  reg.ICPConvergenceCriteria(max_iteration=60))
    return (synth.alignment_error_m(scan, np.asarray(result.transformation)), time.perf_counter() - t0,
            time.process_time() - c0)


def multistart(mesh) -> None:
    """The multi-start search's starts together against one after the other (see the module docstring)."""
    from unittest import mock

    from scanrig.inspect import coarse
    from scanrig.inspect.closest import CadIndex
    from scanrig.inspect.icp import IcpTrials, robust_icp
    from tests.inspect import synth

    def one_by_one(points_m, index, starts, *, weight_fn, size_m, max_iterations):
        fits = [robust_icp(points_m, index, start, weight_fn=weight_fn, size_m=size_m, max_iterations=max_iterations)
                for start in starts]
        return IcpTrials(np.stack([f.cad_from_cloud for f in fits]), np.full(len(fits), np.nan),
                         np.stack([np.eye(6)] * len(fits)), np.array([f.iterations for f in fits]))

    scan = synth.scan_of(mesh, np.random.default_rng(1), 40_000, outlier_fraction=0.1)
    sparse = CadIndex(mesh, np.random.default_rng(1)).sparse(coarse.TRIAL_SAMPLES, np.random.default_rng(2))
    size_m = float(np.linalg.norm(mesh.extents))
    cpu = {"together": [], "one after the other": []}
    poses = {}
    for rep in range(3):
        for name in cpu:
            with mock.patch.object(coarse, "icp_trials", one_by_one) if name != "together" else nullcontext():
                c0 = time.process_time()
                poses[name] = coarse._multistart(scan.points_m, sparse, size_m, np.random.default_rng(rep))
                cpu[name].append(time.process_time() - c0)
    together, alone = (np.median(cpu[name]) for name in cpu)
    difference = max(np.abs(a - b).max() for a, b in zip(poses["together"], poses["one after the other"]))
    print(f"multi-start search, 125 starts on {coarse.TRIAL_POINTS} points: together {together:.2f} s CPU, "
          f"one after the other {alone:.2f} s CPU ({alone / together:.2f}x); poses differ by {difference:.1e}")


def main() -> None:
    from scanrig.inspect import inspect_cloud, write_inspection
    from scanrig.report.inspection_page import write_inspection_page
    from tests.inspect import synth

    n_seeds = int(next((a for a in sys.argv[1:] if a.isdigit()), 3))
    with open("/proc/loadavg") as f:
        print(f"load average at start: {f.read().split()[0]}")
    mesh = synth.bracket_mesh()
    if "--multistart" in sys.argv:
        multistart(mesh)
        return
    tolerance_m = 1e-4
    for seed in range(n_seeds):
        scan = synth.scan_of(mesh, np.random.default_rng(seed), 40_000)
        t0, c0 = time.perf_counter(), time.process_time()
        result = inspect_cloud(scan.points_m, mesh, tolerance_m=tolerance_m, seed=seed)
        elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
        bump = np.abs(synth.bump_height_errors_m(scan, result.deviation_m)).max()
        if importlib.util.find_spec("open3d") is None:
            baseline = "baseline skipped: Open3D is not installed (the open3d extra)"
        else:
            base_err, base_s, base_cpu = baseline_open3d(scan, mesh, seed)
            baseline = (f"baseline Open3D point-to-plane ICP from identity: alignment error {1e3 * base_err:.3f} mm, "
                        f"{base_s:.1f} s ({base_cpu:.1f} s CPU)")
        print(f"seed {seed}: 40 000 points, {result.alignment.method}: alignment error "
              f"{1e3 * synth.alignment_error_m(scan, result.cad_from_cloud):.5f} mm RMS, deviation error "
              f"{synth.deviation_error_m(scan, result.deviation_m) / synth.NOISE_M:.3f} x noise, worst bump height "
              f"error {1e3 * bump:.4f} mm, {elapsed:.1f} s ({cpu:.1f} s CPU) | {baseline}")
    if "--no-million" in sys.argv:
        return
    scan = synth.scan_of(mesh, np.random.default_rng(100), 1_000_000)
    t0, c0 = time.perf_counter(), time.process_time()
    result = inspect_cloud(scan.points_m, mesh, tolerance_m=tolerance_m, seed=100)
    t1, c1 = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        write_inspection(result, Path(tmp), points_m=scan.points_m, title="benchmark")
        write_inspection_page(result, Path(tmp), points_m=scan.points_m, title="benchmark")
    t2, c2 = time.perf_counter(), time.process_time()
    print(f"1 000 000 points: inspect_cloud {t1 - t0:.1f} s ({c1 - c0:.1f} s CPU), files {t2 - t1:.1f} s "
          f"({c2 - c1:.1f} s CPU), end to end {t2 - t0:.1f} s ({c2 - c0:.1f} s CPU, both cores counted); "
          f"alignment error {1e3 * synth.alignment_error_m(scan, result.cad_from_cloud):.5f} mm, deviation error "
          f"{synth.deviation_error_m(scan, result.deviation_m) / synth.NOISE_M:.3f} x noise")
    with open("/proc/loadavg") as f:
        print(f"load average at end: {f.read().split()[0]}")


if __name__ == "__main__":
    main()
