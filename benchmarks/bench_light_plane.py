"""Light-plane calibration: accuracy and honesty of its sigma, over seeds.

1. Synthetic stripe points (no rendering): a camera with f = 1000 px, the laser 0.12 m beside it,
   6 target poses at 0.3-0.6 m tilted 15-30 deg, 0.2 px stripe noise, pose errors of 0.2 mrad and
   0.05 mm per pose; with and without 10 % junk beside the stripe.
2. Rendered sessions: `write_light_plane_shots` (8 poses of the 9 x 6 chessboard, an 800 x 640
   camera with f = 600 px and distortion), then `scanrig calibrate SESSION --light-plane` (camera
   calibration from the laser-off twins, stripe detection, robust fit); the plane compared with
   the true sheet in the world frame of rig.toml (the target at the reference shot).

Prints, per part: worst normal angle error (deg), worst offset error (mm), and the spread of the
normalised errors (error / sigma; 1 = honest sigma).

Run: python benchmarks/bench_light_plane.py [n_seeds]
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def synthetic(n_seeds: int) -> None:
    from scanrig.reconstruct.light_plane_fit import calibrate_light_plane
    from tests.reconstruct import light_plane_synth as synth

    normal_true, offset_true = synth.laser_plane()
    for junk in (False, True):
        z, angle, offset = [], [], []
        for seed in range(n_seeds):
            rng = np.random.default_rng(seed)
            planes, pixels, junk_px = synth.observation(rng, junk_fraction=0.1)
            if junk:
                pixels = [np.vstack([q, j]) for q, j in zip(pixels, junk_px)]
            plane = calibrate_light_plane(synth.camera(), planes, pixels, rng).plane
            a, o = synth.angle_and_offset_error(plane, normal_true, offset_true)
            angle.append(a)
            offset.append(abs(o))
            z.append(synth.normalised_errors(plane, normal_true, offset_true))
        z = np.array(z)
        print(f"synthetic{' + 10 % junk' if junk else ''}: {n_seeds} seeds, worst normal {max(angle):.4f} deg, "
              f"worst offset {1e3 * max(offset):.4f} mm, normalised error spread {z.std():.2f} "
              f"(offset {z[:, 0].std():.2f}, tilts {z[:, 1].std():.2f} {z[:, 2].std():.2f})")


def rendered(n_seeds: int) -> None:
    from scanrig.cli.main import main
    from scanrig.geometry import Camera, Rig
    from scanrig.reconstruct.light_plane import load_light_plane
    from scanrig.sim.calibration_shots import default_target
    from scanrig.sim.library import load_scene
    from scanrig.sim.light_plane_shots import write_light_plane_shots
    from scanrig.targets import save_target
    from tests.reconstruct import light_plane_synth as synth

    room = load_scene("default")
    K = np.array([[600.0, 0, 399.5], [0, 600.0, 319.5], [0, 0, 1]])
    cam = Camera.from_opencv("cam0", K, np.array([-0.1, 0.05, 0, 0, 0]), np.eye(3), np.zeros(3), 800, 640)
    z, angle, offset, seconds = [], [], [], []
    for seed in range(n_seeds):
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp)
            target = default_target("chessboard")
            save_target(target, out / "target.toml")
            write_light_plane_shots(out, room, Rig([cam]), target, 8, np.random.default_rng(seed), workers=2)
            t0 = time.perf_counter()
            with contextlib.redirect_stdout(io.StringIO()):
                status = main(["calibrate", str(out), "--light-plane", "--no-plots", "--no-cross-validate"])
            seconds.append(time.perf_counter() - t0)
            if status != 0:
                print(f"seed {seed}: exit {status}")
                continue
            plane, _ = load_light_plane(out / "light_plane.toml")
            truth = synth.true_plane_in_rig_world(out)
        a, o = synth.angle_and_offset_error(plane, *truth)
        angle.append(a)
        offset.append(abs(o))
        z.append(synth.normalised_errors(plane, *truth))
    z = np.array(z)
    print(f"rendered: {len(z)} seeds, worst normal {max(angle):.4f} deg, worst offset {1e3 * max(offset):.4f} mm, "
          f"normalised error spread {z.std():.2f} (offset {z[:, 0].std():.2f}, tilts {z[:, 1].std():.2f} "
          f"{z[:, 2].std():.2f}); calibrate --light-plane {np.median(seconds):.1f} s median")


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    synthetic(n)
    rendered(n)
