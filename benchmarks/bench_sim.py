"""Simulator speed: laser-free frame, laser frame, whole session (issue 3 acceptance figures).

Run ``python benchmarks/bench_sim.py [--quick]``. Each figure is printed with its target and with
a naive baseline measured in the same run:

* laser-free frame (default scene, 1280x1024): adaptive edge supersampling vs supersampling
  every pixel (the obvious way to integrate pixels);
* calibration shot (the cube in the default room, 8x8 rays per edge pixel): edge pixels on one
  flat, matte, evenly lit plane met in closed form vs every edge pixel's rays cast;
* laser frame: rendering only the window the trace can touch (plus fast full-frame noise) vs
  re-rendering the whole frame with the laser;
* stripe frame (the demo's sweep of 100 upright sheets, every tenth; one camera): sub-pixel rays
  only in the window's pixels the laser may light vs in every pixel of the window;
* session (3 cameras, spot, default scene, PNG files written): 2 worker processes vs 1.

``--quick`` shrinks the baselines and the session (frames and times are reported as measured).
The two frame figures are the best of three runs, wall and CPU time each taken at its minimum
(the machine may be shared: CPU time of this single-threaded process is the steadier figure).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from unittest import mock

import numpy as np

from scanrig.sim import (
    CameraView,
    default_rig,
    load_scene,
    raster_poses,
    simulate_session,
    trace_laser,
)
from scanrig.sim import render
from scanrig.sim.calibration_shots import calibration_sensor, default_target, random_pose, target_scene
from scanrig.sim.render import _subpixel_samples

_CPU: dict = {}   # figure -> CPU seconds of this process (a load-independent view of one core)


def _timed(fn, repeat=1, cpu_key=None):
    """Best wall time of ``repeat`` runs; the best CPU time (on a loaded machine, not necessarily
    of the same run) goes to ``_CPU[cpu_key]``."""
    best = np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        best = min(best, time.perf_counter() - t0)
        if cpu_key:
            _CPU[cpu_key] = min(_CPU.get(cpu_key, np.inf), time.process_time() - c0)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller baselines and session (< ~1 min unloaded)")
    args = parser.parse_args()

    scene = load_scene("default")
    rig = default_rig(3, scene.center_m, scene.rig)
    cam = rig["cam1"]
    scene.raycaster  # noqa: B018 - build the BVH outside the timings
    rows = []

    # 1. laser-free frame (a new view each time: includes solving the camera's pixel ray table)
    t_bg = _timed(lambda: CameraView(cam, scene).background_e, repeat=3, cpu_key="laser-free frame 1280x1024")
    s = scene.sensor.supersampling
    # baseline: every pixel supersampled (s x s rays); --quick renders one quarter and scales up
    frac = 0.25 if args.quick else 1.0
    view = CameraView(cam, scene)
    h = int(cam.height * frac)
    u, v = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(h, dtype=float))
    q = np.column_stack([u.ravel(), v.ravel()])
    offsets = (np.arange(s) + 0.5) / s - 0.5
    dv, du = np.meshgrid(offsets, offsets, indexing="ij")
    sub = (q[:, None, :] + np.column_stack([du.ravel(), dv.ravel()])[None]).reshape(-1, 2)
    view.ray_table.xy  # noqa: B018 - same solve as the measured path; not the point of the baseline
    t_full = _timed(lambda: view._radiance_background(*view.ray_table.rays(sub))) / frac
    rows.append(("laser-free frame 1280x1024", t_bg, 2.0, f"all pixels {s}x{s}", t_full))

    # 1b. calibration shot: the same image, with and without the closed-form rays on planes
    target = default_target("cube")
    shot = target_scene(target, random_pose(target, rig, scene.center_m, scene.radius_m, np.random.default_rng(0),
                                            scene.rig.cover_field), scene)
    shot_key = "calibration shot (cube) 1280x1024"
    shot_view = lambda: CameraView(cam, shot, calibration_sensor(scene)).background_e  # noqa: E731
    t_shot = _timed(shot_view, repeat=3, cpu_key=shot_key)
    with mock.patch.object(render, "planar_pixels", lambda pixels, obj, hits: np.zeros(pixels.size, bool)):
        t_cast = _timed(shot_view, repeat=1 if args.quick else 3, cpu_key="every edge ray cast")
    rows.append((shot_key, t_shot, None, "every edge ray cast", t_cast))   # no target: a speed-up

    # 2. laser frame
    view = CameraView(cam, scene, rng=np.random.default_rng(0))
    view.noise  # noqa: B018
    poses = raster_poses(scene.laser, scene.center_m, scene.radius_m, 64, "spot")
    traces = [trace_laser(p, scene.laser, scene) for p in poses]
    rng = np.random.default_rng(1)
    n = len(traces)

    def laser_frames():
        for pose in poses:                   # trace (shared by all cameras) + one camera's frame
            view.frame(trace_laser(pose, scene.laser, scene), rng)

    t_frame = _timed(laser_frames, repeat=3, cpu_key="laser frame (spot, 1 camera)") / n
    _CPU["laser frame (spot, 1 camera)"] /= n
    # baseline: the laser's radiance at every pixel centre (no supersampling even) + exact noise
    q_all = np.column_stack([np.tile(np.arange(cam.width, dtype=float), cam.height),
                             np.repeat(np.arange(cam.height, dtype=float), cam.width)])
    n_base = 1 if args.quick else 3
    t_naive = _timed(lambda: view.sensor.expose(
        view.background_e + view.laser_radiance(q_all, traces[n // 2]).reshape(cam.height, cam.width)
        * view.sensor.e_per_radiance, rng), repeat=n_base)
    rows.append(("laser frame (spot, 1 camera)", t_frame, 0.020, "full-frame laser render", t_naive))

    # 3. stripe frame: trace + one camera's frame, over the demo's sweep
    sheets = raster_poses(scene.laser, scene.center_m, scene.radius_m, 100, "stripe")[::25 if args.quick else 10]

    def stripe_frames():
        for pose in sheets:
            view.frame(trace_laser(pose, scene.laser, scene), rng)

    def every_window_pixel():                # the laser's radiance at all sub-pixel samples of the window
        for pose in sheets:
            trace = trace_laser(pose, scene.laser, scene)
            mask, u0, v0 = view.window_mask(trace)
            rows, cols = np.nonzero(mask)
            view.laser_radiance(_subpixel_samples(np.column_stack([cols + u0, rows + v0]).astype(float), s), trace)

    stripe_key = "stripe frame (demo sweep, 1 camera)"
    t_stripe = _timed(stripe_frames, repeat=1 if args.quick else 3, cpu_key=stripe_key) / len(sheets)
    _CPU[stripe_key] /= len(sheets)
    t_every = _timed(every_window_pixel, cpu_key="every window pixel") / len(sheets)
    _CPU["every window pixel"] /= len(sheets)
    rows.append((stripe_key, t_stripe, 1.0, "every window pixel", t_every))

    # 4. whole session
    n_frames = 60 if args.quick else 500
    out = tempfile.mkdtemp(prefix="bench_sim_")
    try:
        t_sess = _timed(lambda: simulate_session(f"{out}/a", scene, rig=rig, mode="spot", n_frames=n_frames,
                                                 rng=np.random.default_rng(2), with_calibration=False, workers=2))
        n_serial = max(10, n_frames // 10)
        t_serial = _timed(lambda: simulate_session(f"{out}/b", scene, rig=rig, mode="spot", n_frames=n_serial,
                                                   rng=np.random.default_rng(2), with_calibration=False,
                                                   workers=1)) * n_frames / n_serial
    finally:
        shutil.rmtree(out, ignore_errors=True)
    target = 60.0 * n_frames / 500
    rows.append((f"session 3 cams x {n_frames} spot frames", t_sess, target, "1 worker (scaled)", t_serial))

    print(f"{'figure':<38} {'wall':>9} {'cpu':>9} {'target':>9} {'baseline':>30} {'baseline/wall':>14}")
    for name, t, target_s, base_name, t_base in rows:
        cpu = f"{_CPU[name]:.3f}s" if name in _CPU else "n/a"
        target_text = "-" if target_s is None else f"{target_s:.3f}s"
        print(f"{name:<38} {t:>8.3f}s {cpu:>9} {target_text:>9} {base_name + f' {t_base:.3f}s':>30} "
              f"{t_base / t:>13.1f}x")
    print("wall = elapsed time (other work on the machine slows it down); cpu = this process's CPU time")
    print(f"stripe frame CPU: {_CPU[stripe_key]:.3f} s; the laser's radiance alone at every sub-pixel sample of the window: "
          f"{_CPU['every window pixel']:.3f} s ({_CPU['every window pixel'] / _CPU[stripe_key]:.1f}x)")
    print(f"calibration shot CPU: {_CPU[shot_key]:.3f} s; every edge ray cast: {_CPU['every edge ray cast']:.3f} s "
          f"({_CPU['every edge ray cast'] / _CPU[shot_key]:.2f}x)")


if __name__ == "__main__":
    main()
