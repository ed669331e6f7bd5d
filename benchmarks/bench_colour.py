"""Colour cameras in the simulator: cost per frame and what the colour_stripe scene's stripe looks like.

Run ``python benchmarks/bench_colour.py [--frames N]``. On the built-in ``colour_stripe`` scene
(one 1280x1024 camera, stripe raster of N frames) it prints:

* time per frame (render + write; wall and CPU time of this process, the steadier figure on a
  shared machine) of the same scene with a grey camera and with its colour camera, both through
  the fast per-frame path (background once, laser windows);
* the stripe as stored (Bayer, JPEG 90): over the rows where the beam's direct peak exceeds 3x the
  full well, the median width of the band where R >= 250, of the band where G is within 5 DN of
  its peak, the median peak in units of the full well (direct and after the halo), and how often
  G's and B's maxima lie within 1 px of the true centre.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from scanrig.io.session import read_image
from scanrig.sim import load_scene, raster_poses, trace_laser
from scanrig.sim.colour import subsurface_halo, write_frame
from scanrig.sim.laser_exposure import nominal_peak_e_per_W
from scanrig.sim.render import CameraView
from scanrig.sim.scan_setup import scene_rig

#: Rows whose direct laser peak exceeds this multiple of the full well are measured.
STRONG_ROW_FULL_WELLS = 3.0
HALF_PX = 12


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=8)
    args = parser.parse_args()
    scene = load_scene("colour_stripe")
    camera = scene_rig(scene, 1).cameras[0]
    traces = [trace_laser(p, scene.laser, scene)
              for p in raster_poses(scene.laser, scene.center_m, scene.radius_m, args.frames, "stripe")]
    with tempfile.TemporaryDirectory() as tmp:
        for name, sc in (("grey", replace(scene, colour=None)), ("colour", scene)):
            view = CameraView(camera, sc, rng=np.random.default_rng(0))
            view.noise  # noqa: B018 - background and noise bank once, as a session does
            rng = np.random.default_rng(1)
            t0, c0 = time.perf_counter(), time.process_time()
            files = [write_frame(Path(tmp) / f"{name}{i:03d}", view.sensor_frame(tr, rng), view.colour)
                     for i, tr in enumerate(traces)]
            wall = (time.perf_counter() - t0) / len(traces) * 1e3
            cpu = (time.process_time() - c0) / len(traces) * 1e3
            print(f"{name:6s} frame (render + write): {wall:.0f} ms wall, {cpu:.0f} ms CPU")
        _stripe_figures(scene, view, traces, files)


def _stripe_figures(scene, view, traces, files) -> None:
    full_well = scene.sensor.full_well_e
    r_band, g_band, direct, halo, g_ok, b_ok = [], [], [], [], [], []
    for trace, path in zip(traces, files):
        window = view.laser_window(trace)
        if window is None:
            continue
        image = read_image(path).astype(np.int64)
        rows = np.flatnonzero(window.electrons.max(axis=1) > STRONG_ROW_FULL_WELLS * full_well)
        centre = window.electrons.argmax(axis=1)[rows] + window.u0
        cols = centre[:, None] + np.arange(-HALF_PX, HALF_PX + 1)
        inside = (cols.min(axis=1) >= 0) & (cols.max(axis=1) < image.shape[1])
        rows, cols = rows[inside], cols[inside]
        profile = image[(rows + window.v0)[:, None], cols]
        r_band += (profile[..., 0] >= 250).sum(axis=1).tolist()
        g_band += (profile[..., 1] >= profile[..., 1].max(axis=1, keepdims=True) - 5).sum(axis=1).tolist()
        offset = np.abs(profile.argmax(axis=1) - HALF_PX)
        g_ok += (offset[:, 1] <= 1).tolist()
        b_ok += (offset[:, 2] <= 1).tolist()
        grown = window.padded(scene.colour.halo_pad_px, view.background_e.shape)
        direct += (window.electrons[rows].max(axis=1) / full_well).tolist()
        halo_rows = rows + window.v0 - grown.v0
        halo += (subsurface_halo(grown.electrons, scene.colour)[halo_rows].max(axis=1) / full_well).tolist()
    print(f"rows measured: {len(r_band)} (direct peak > {STRONG_ROW_FULL_WELLS:g}x full well)")
    nominal = scene.laser.stripe_power_W * nominal_peak_e_per_W(scene.laser, scene.sensor, scene.rig,
                                                                 scene.center_m, "stripe") / full_well
    print(f"median peak / full well: direct {np.median(direct):.1f}, after the halo {np.median(halo):.1f} "
          f"(laser_overexposure {nominal:.3g} nominal)")
    print(f"median band: R >= 250 over {np.median(r_band):.0f} px, G within 5 DN of its peak over "
          f"{np.median(g_band):.0f} px")
    print(f"G max within 1 px of the true centre: {np.mean(g_ok):.1%}, B: {np.mean(b_ok):.1%}")


if __name__ == "__main__":
    main()
