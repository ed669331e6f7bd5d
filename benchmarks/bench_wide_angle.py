"""Wide-angle calibration benchmark: a simulated 165-degree fisheye (scene ``fisheye``, OPENCV8
truth) calibrated from its images and from ``--corners``, errors of fx fy cx cy against the truth
and their stated sigma.

Run ``python benchmarks/bench_wide_angle.py`` (renders a 60-shot ChArUco session into a temporary
folder, ~2 minutes on an idle machine) or ``--session DIR`` for a session rendered before with
``scanrig simulate DIR --scene fisheye --cameras 1 --target charuco --shots 60 --frames 1``.

The ``--corners`` input holds every target point the true camera sees at the true poses
(``truth/target_poses.csv``), in front of it, inside the image and seen less than 70 degrees from
the board normal, with Gaussian noise of ``--sigma`` px: the field up to the image corners,
which the detector on rendered images reaches less often. For each input it prints the median
view RMS of Zhang's pinhole start (above 2 px the wide-angle start of
``scanrig.calibration.init_wide`` is tried too), the solve's RMS and, per intrinsic, the error,
the stated sigma and their ratio.
"""

from __future__ import annotations

import argparse
import csv
import tempfile
import time
from pathlib import Path

import numpy as np

from scanrig.calibration.corners_csv import write_corners_csv
from scanrig.calibration.init import _intrinsics, _median_rms, _view_poses
from scanrig.calibration.session_calibration import solve_session
from scanrig.calibration.synthetic import observe
from scanrig.geometry.transform import RigidTransform
from scanrig.io.rig_file import load_rig
from scanrig.targets import load_target


def truth_poses(session: Path) -> list[RigidTransform]:
    """``world_from_target`` of every shot, from ``truth/target_poses.csv``."""
    with open(session / "truth" / "target_poses.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return [RigidTransform(np.array([float(r[f"r{i}{j}"]) for i in (1, 2, 3) for j in (1, 2, 3)]).reshape(3, 3),
                           np.array([float(r[k]) for k in ("tx", "ty", "tz")])) for r in rows]


def report(label: str, session: Path, corners: Path | None) -> None:
    truth = load_rig(session / "truth" / "rig.toml")
    t0 = time.perf_counter()
    result, obs = solve_session(session, "opencv8", corners, cross_validate=False)
    seconds = time.perf_counter() - t0
    target = result.target
    for c, cam in enumerate(result.rig.cameras):
        zhang = _median_rms(_view_poses(_intrinsics(obs, target, c, "opencv8"), obs, target, c))
        error = cam.params[:4] - truth[cam.name].params[:4]
        sigma = result.uncertainty.params_std[cam.name][:4]
        print(f"{label}: {cam.name} {int(result.bundle.inliers.sum())} corners in "
              f"{len({int(s) for s in obs.shot[obs.camera == c]})} views, Zhang start median view RMS {zhang:.3g} px, "
              f"solve RMS {result.bundle.rms_px(c):.4f} px, {len(result.init.dropped_views)} views dropped, "
              f"{seconds:.1f} s")
        for name, e, s in zip(("fx", "fy", "cx", "cy"), error, sigma):
            print(f"    {name}: error {e:+.4f} px, sigma {s:.4f} px, |error|/sigma {abs(e) / s:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--session", type=Path, help="a simulated fisheye session (default: render one)")
    parser.add_argument("--shots", type=int, default=60)
    parser.add_argument("--seed", type=int, default=4)
    parser.add_argument("--sigma", type=float, default=0.1, help="noise of the --corners input, px")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        session = args.session
        if session is None:
            from scanrig.sim.session_writer import simulate_session

            session = Path(tmp) / "fisheye"
            simulate_session(session, "fisheye", n_cameras=1, n_frames=1, rng=np.random.default_rng(args.seed),
                             n_shots=args.shots, target_kind="charuco", workers=2)
        report("images", session, None)
        truth = load_rig(session / "truth" / "rig.toml")
        obs = observe(list(truth.cameras), load_target(session / "target.toml"), truth_poses(session), args.sigma,
                      np.random.default_rng(args.seed))
        corners = Path(tmp) / "truth_corners.csv"
        write_corners_csv(obs, corners)
        report(f"--corners (truth + {args.sigma} px noise)", session, corners)


if __name__ == "__main__":
    main()
