"""Projection and back-projection throughput against OpenCV, 1M points, same run.

Baselines: ``cv2.projectPoints`` for projection; ``cv2.undistortPoints`` with termination
criteria (OpenCV's iterative undistortion, ``undistortPointsIter`` in OpenCV 4's Python API) for
back-projection, run with the fewest iterations that reach the same accuracy as scanrig's Newton
solve, or 1e-6 px if scanrig is more accurate than that (accuracy: the largest pixel error of
re-projecting the result, over all points). Two OpenCV criteria are timed: ``COUNT | EPS``
(eps 1e-15, which makes OpenCV also compute the reprojection error in every iteration) and
``COUNT`` alone, the fastest way to run OpenCV to a given accuracy. For rays (pixels -> unit
world directions) OpenCV's time is that of ``undistortPoints`` alone: the conversion of its
normalised coordinates to world rays is not counted, which favours OpenCV.

Run: ``python benchmarks/bench_camera.py [--quick]``
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from scanrig.geometry import Camera, RigidTransform

#: Pixel accuracy both back-projections must reach to be compared for speed.
TARGET_ACCURACY_PX = 1e-6


def best_time(fun, repeats: int) -> float:
    """Shortest wall time of ``repeats`` calls, seconds."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fun()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats")
    parser.add_argument("--points", type=int, default=1_000_000)
    args = parser.parse_args()
    repeats = 2 if args.quick else 5
    cv2.setNumThreads(1)
    rng = np.random.default_rng(0)
    n = args.points
    cam = Camera("bench", "opencv5", [1800.0, 1800.0, 640.0, 512.0, -0.25, 0.12, 1e-3, -5e-4, -0.02],
                 1280, 1024, RigidTransform.from_rvec_tvec([0.1, -0.2, 0.05], [0.05, 0.02, 1.0]))
    xy = rng.uniform([-0.35, -0.28], [0.35, 0.28], (n, 2))
    z = rng.uniform(0.5, 2.0, n)
    p_world = cam.cam_from_world.inverse().apply(np.c_[xy * z[:, None], z])
    K, dist, R, t = cam.to_opencv()
    rvec = cv2.Rodrigues(R)[0]

    t_ours = best_time(lambda: cam.project(p_world), repeats)
    t_cv = best_time(lambda: cv2.projectPoints(p_world, rvec, t, K, dist), repeats)
    q = cam.project(p_world)
    q_cv = cv2.projectPoints(p_world, rvec, t, K, dist)[0][:, 0]
    print(f"points: {n:,}  (opencv {cv2.__version__}, numpy {np.__version__}, one OpenCV thread)")
    print(f"{'operation':<34}{'scanrig':>12}{'OpenCV':>12}{'speed ratio':>14}{'max |diff| px':>16}")
    print(f"{'project (world -> pixels)':<34}{n / t_ours / 1e6:>9.2f} M/s{n / t_cv / 1e6:>9.2f} M/s"
          f"{t_cv / t_ours:>13.2f}x{np.abs(q - q_cv).max():>16.1e}")

    def err_px(xy_norm):
        back = cam.project_cam(np.c_[xy_norm, np.ones(len(xy_norm))])
        return np.nanmax(np.abs(back - q))

    xy_ours, ok = cam.unproject(q)
    err_ours = err_px(xy_ours)
    target = max(err_ours, TARGET_ACCURACY_PX)
    q_cv_in = q.reshape(-1, 1, 2)

    def cv_undistort(crit):
        return cv2.undistortPoints(q_cv_in, K, dist, None, np.eye(3), np.eye(3), crit)[:, 0]

    baselines = []  # (label, criteria, iterations, error px)
    for label, kind in (("COUNT|EPS", cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS),
                        ("COUNT", cv2.TERM_CRITERIA_COUNT)):
        for iters in range(1, 101):  # the fewest iterations that reach the target
            crit = (kind, iters, 1e-15)
            err_cv = err_px(cv_undistort(crit))
            if err_cv <= target:
                break
        baselines.append((label, crit, iters, err_cv))

    t_un = best_time(lambda: cam.unproject(q), repeats)
    t_rays = best_time(lambda: cam.rays(q), repeats)
    t_cv = {label: best_time(lambda crit=crit: cv_undistort(crit), repeats) for label, crit, _, _ in baselines}
    origins, dirs = cam.rays(q)
    err_rays = np.nanmax(np.abs(cam.project(origins + 2.0 * dirs) - q))
    for label, _, _, _ in baselines:
        print(f"{'unproject (pixels -> normalised)':<34}{n / t_un / 1e6:>9.2f} M/s{n / t_cv[label] / 1e6:>9.2f} M/s"
              f"{t_cv[label] / t_un:>13.2f}x{'':>16}  OpenCV {label}")
    for label, _, _, _ in baselines:
        print(f"{'rays (pixels -> world rays)':<34}{n / t_rays / 1e6:>9.2f} M/s{n / t_cv[label] / 1e6:>9.2f} M/s"
              f"{t_cv[label] / t_rays:>13.2f}x{'':>16}  OpenCV {label}, undistortPoints only")
    print(f"  accuracy (max reprojection error over all {n:,} points): scanrig unproject {err_ours:.1e} px, "
          f"rays {err_rays:.1e} px (converged {ok.mean():.4%}); target {target:.1e} px")
    for label, _, iters, err_cv in baselines:
        print(f"  accuracy: OpenCV {label} {err_cv:.1e} px with {iters} iterations (fewest reaching the target)")


if __name__ == "__main__":
    main()
