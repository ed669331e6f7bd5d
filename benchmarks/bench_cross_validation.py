"""Cross-validation benchmark: does the stated uncertainty predict how independent halves differ?

Run ``python benchmarks/bench_cross_validation.py`` (20 seeds x 10, 20, 40, 80 shots) or
``--seeds 3 --shots 10,20`` for a quick look. Simulated corners (no rendering): three cameras
30 deg apart 0.8 m from the default 0.2 m ChArUco cube (opencv5, f 1400 px, 1280x1024), the cube
moved over every camera's field of view (``covering_target_poses``), corners seen up to 70 deg from
their face normal while their squares image >= 16 px, Gaussian noise of 0.1 px.

With ``--caliscope`` it also calibrates the real 4-webcam ChArUco rig of
``../shared/data/caliscope-4cam-charuco`` (opencv4, rig views alone) and prints its
cross-validation and warnings.

For each camera it prints the whitened ratio pooled over the four splits of the shots into
halves (``sqrt(sum chi2 / sum dof)``, each split's halves' difference whitened by ``Sigma_A +
Sigma_B``; 1 when the sigmas are right), each split's own whitened ratio, and, for comparison,
the plain ratio of the pooled RMS pixel differences, measured / predicted, which one or two
directions (the principal point) dominate. The acceptance of the cross-validation is the pooled
ratio within 0.5-2 on every seed and shot count, median near 1, and no single split's ratio above
RATIO_WARN (a warning) on these clean sessions. When the sigmas are right, ``ratio² dof`` is
chi-square over ``dof`` directions: for one split alone about 1 % of the ratios fall below 0.5 at
9 directions by chance, for the pooled ratio (~36 directions) 1e-6, so the summary prints per
split how many chance puts outside 0.5-2 and how many exceed RATIO_WARN, and the smallest
chi-square tail probability of all the pooled checks. Whether those tail probabilities are
uniform, as they are when the sigmas are right and the splits independent, it judges by a
Kolmogorov-Smirnov test per camera (the three cameras of a session share its shots, so their
ratios are correlated) and by the counts below 1e-2 and 1e-3 against their expectation.
``--first-seed 20 --seeds 420 --shots 20`` draws fresh sessions for that: the first 20 seeds are
those the acceptance table was read from.

Last, each camera's corners solved alone against the rig (``scanrig.calibration.camera_agreement``)
over every session: the ratios, the smallest chance, how many were warned about (false alarms on
these sessions, whose cameras see every shot at the same instant) and whether the chances are
uniform.

With ``--correlation`` it measures instead how independent the splits are (e.g.
``--correlation --seeds 3 --shots 10,20,40,80``): the corners' noise carried linearly through
every half (exact at this noise: the halves' non-linear remainder is below 0.11 sigma), each
split's whitened pixel difference is a linear map of that noise, so the canonical correlations
between two splits' whitened differences are exact, and with them the variance of the pooled
chi-square relative to chi-square over the summed directions, ``1 + 2 sum rho² / sum dof``
(1 when the splits are independent).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import itertools
import time
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2, kstest

from scanrig.calibration.camera_agreement import P_WARN
from scanrig.calibration.cross_validation import (RATIO_WARN, SPLITS, CameraCrossValidation, _projection_jacobian,
                                                  _sigma_modes, common_points, split_halves, whitening)
from scanrig.calibration.pipeline import _solve_half, calibrate
from scanrig.calibration.synthetic import DETECTABLE_SQUARE_PX, ring_cameras, simulate
from scanrig.calibration.uncertainty import parameter_covariance
from scanrig.targets import charuco, cube

SIGMA_PX = 0.1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0, help="seeds run from here (fresh draws: 20 and on)")
    parser.add_argument("--shots", default="10,20,40,80", help="comma-separated shot counts")
    parser.add_argument("--caliscope", action="store_true", help="also the real 4-webcam rig")
    parser.add_argument("--correlation", action="store_true", help="how independent the splits are, instead")
    args = parser.parse_args()
    if args.caliscope:
        caliscope()
    target = cube()
    if args.correlation:
        for n_shots in (int(s) for s in args.shots.split(",")):
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                split_correlation(target, n_shots, seed)
        return
    with open("/proc/loadavg") as f:
        print(f"load: {f.read().strip()}")
    print("shots seed  time | per camera: pooled whitened ratio (dof); each split's whitened ratio; "
          "RMS measured / predicted px = plain ratio")
    checks = {}       # shots -> [Check]
    agreements = []   # CameraAgreement of every camera that shares shots
    for n_shots in (int(s) for s in args.shots.split(",")):
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            rng = np.random.default_rng(seed)
            cams = ring_cameras(3, rng=rng)
            sim = simulate(cams, target, n_shots, SIGMA_PX, rng, cover=True, min_square_px=DETECTABLE_SQUARE_PX)
            t0 = time.perf_counter()
            result = calibrate(sim.obs, target, "opencv5")
            elapsed = time.perf_counter() - t0
            cv = result.cross_validation
            if cv is None:
                print(f"{n_shots:5d} {seed:4d} {elapsed:5.1f}s | not run (a half could not be solved)")
                continue
            agreements += [a for a in result.camera_agreement.values() if a is not None]
            parts = []
            for name, r in cv.cameras.items():
                if r is None:
                    parts.append(f"{name}: no common area")
                    continue
                splits = {split: cameras[name] for split, cameras in cv.splits.items() if cameras[name] is not None}
                checks.setdefault(n_shots, []).append(Check(r, seed, name, splits))
                parts.append(f"{name}: {r.ratio:.2f} ({r.dof}); "
                             + ", ".join(f"{c.ratio:.2f}" for c in splits.values())
                             + f"; {r.measured_px:.3f}/{r.predicted_px:.3f} px = {r.measured_px / r.predicted_px:.2f}")
            print(f"{n_shots:5d} {seed:4d} {elapsed:5.1f}s | " + "; ".join(parts), flush=True)
    print("\nshots | pooled whitened ratio: median [min, max], outside 0.5-2 (by chance) | plain ratio: median "
          "[min, max], outside 0.5-2 | cameras")
    for n_shots, rows in checks.items():
        print(_summary_row(f"{n_shots:5d}", rows))
    every = [row for rows in checks.values() for row in rows]
    print(_summary_row("  all", every))
    print(f"\neach split alone (all shot counts) | whitened ratio: median [min, max], outside 0.5-2 (by chance) | "
          f"above RATIO_WARN {RATIO_WARN:g} (warned)")
    for split in SPLITS:
        alone = [row.splits[split] for row in every if split in row.splits]
        print(f"  {split:20s} | {_whitened_summary([c.ratio for c in alone], [c.dof for c in alone])} | "
              f"{sum(c.ratio > RATIO_WARN for c in alone)} of {len(alone)}")
    p, row, shots = min(((chi2.sf(row.pooled.ratio ** 2 * row.pooled.dof, row.pooled.dof), row, n)
                         for n, rows in checks.items() for row in rows), key=lambda t: t[0])
    print(f"smallest chi-square tail probability: {p:.1e} ({shots} shots, seed {row.seed}, {row.camera}: ratio "
          f"{row.pooled.ratio:.2f} over {row.pooled.dof} directions)")
    print(_tail_summary(every))
    print(_agreement_summary(agreements))


@dataclass(frozen=True)
class Check:
    """One camera's cross-validation in one simulated session: pooled, and each split's (name -> figures)."""

    pooled: CameraCrossValidation
    seed: int
    camera: str
    splits: dict


def _summary_row(label: str, rows: list) -> str:
    """One line of the summary table over :class:`Check` rows."""
    p = np.array([row.pooled.measured_px / row.pooled.predicted_px for row in rows])
    return (f"{label} | {_whitened_summary([row.pooled.ratio for row in rows], [row.pooled.dof for row in rows])} | "
            f"{np.median(p):.2f} [{p.min():.2f}, {p.max():.2f}], {_outside(p)} | {len(p)}")


def _whitened_summary(ratios: list, dofs: list) -> str:
    """Median [min, max] of whitened ratios, how many lie outside 0.5-2 and, in brackets, how many
    chance puts there when the sigmas are right (``ratio² dof`` chi-square over ``dof`` directions)."""
    w, dof = np.array(ratios), np.array(dofs)
    w, dof = w[dof > 0], dof[dof > 0]
    chance = np.sum(chi2.cdf(0.25 * dof, dof) + chi2.sf(4.0 * dof, dof))
    return f"{np.median(w):.2f} [{w.min():.2f}, {w.max():.2f}], {_outside(w)} ({chance:.2g})"


def _tail_summary(rows: list) -> str:
    """Whether the checks' chi-square tail probabilities are uniform, as they are when the sigmas are right.

    Kolmogorov-Smirnov against uniform per camera (the cameras of one session share its shots, so
    their ratios are correlated; one camera's checks are independent), and the counts below 1e-2
    and 1e-3 against their expectation.
    """
    p = np.array([chi2.sf(row.pooled.ratio ** 2 * row.pooled.dof, row.pooled.dof) for row in rows])
    cameras = np.array([row.camera for row in rows])
    ks = ", ".join(f"{name} {kstest(p[cameras == name], 'uniform').pvalue:.2f}" for name in sorted(set(cameras)))
    return (f"tail probabilities uniform? KS p-value per camera: {ks}; below 1e-2: {np.count_nonzero(p < 1e-2)} "
            f"(expected {1e-2 * len(p):.1f}), below 1e-3: {np.count_nonzero(p < 1e-3)} (expected {1e-3 * len(p):.2f})")


def _agreement_summary(agreements: list) -> str:
    """Each camera's corners alone against the rig over every session: the ratios, the smallest
    probability, the warnings (false alarms on these clean sessions) and a KS test of uniformity."""
    ratio = np.array([a.ratio for a in agreements])
    p = np.array([a.p_value for a in agreements])
    return (f"cameras apart (corners alone vs in the rig): ratio median {np.median(ratio):.2f} "
            f"[{ratio.min():.2f}, {ratio.max():.2f}] over {len(p)} cameras; smallest probability {p.min():.1e}; "
            f"warned (below {P_WARN:g}) {np.count_nonzero(p < P_WARN)}; below 1e-2: {np.count_nonzero(p < 1e-2)} "
            f"(expected {1e-2 * len(p):.1f}); uniform? KS p-value {kstest(p, 'uniform').pvalue:.2f}")


def _outside(ratios: np.ndarray) -> int:
    return int(np.count_nonzero((ratios < 0.5) | (ratios > 2.0)))


def split_correlation(target, n_shots: int, seed: int) -> None:
    """Print per camera how correlated the splits' whitened differences are (see the module docstring)."""
    rng = np.random.default_rng(seed)
    sim = simulate(ring_cameras(3, rng=rng), target, n_shots, SIGMA_PX, rng, cover=True,
                   min_square_px=DETECTABLE_SQUARE_PX)
    full = calibrate(sim.obs, target, "opencv5", cross_validate=False)
    maps = {}      # (split, camera) -> (dof, 2 n_corners): whitened difference per unit noise on each residual
    for split, pattern in SPLITS.items():
        halves = [_solve_half(full, shots, {}) for shots in split_halves(n_shots, pattern)]
        noise_maps = [_noise_map(full.bundle, half) for half in halves]
        covariances = [parameter_covariance(half)[0] for half in halves]
        for c, cam in enumerate(full.rig.cameras):
            p_ref = common_points(full.bundle, halves, c, full.working_distance_m[cam.name])
            modes, difference = [], 0.0
            for sign, half, noise_map, cov in zip((-1, 1), halves, noise_maps, covariances):
                _, G, cols = _projection_jacobian(half, c, 0, p_ref)
                modes.append(_sigma_modes(G, cov[np.ix_(cols, cols)]))
                difference = difference + sign * G.reshape(2 * len(p_ref), -1) @ noise_map[cols]
            U, s = whitening(np.concatenate(modes, axis=1))
            maps[split, cam.name] = (U.T @ difference) / s[:, None]
    names = list(SPLITS)
    for cam in full.rig.names:
        total_dof = sum(len(maps[split, cam]) for split in names)
        parts, rho2 = [], 0.0
        for a, b in itertools.combinations(range(len(names)), 2):
            rho = _canonical_correlations(maps[names[a], cam], maps[names[b], cam])
            rho2 += np.sum(rho ** 2)
            parts.append(f"{names[a]} / {names[b]} {np.sqrt(np.mean(rho ** 2)):.2f} (max {rho.max():.2f})")
        print(f"{n_shots:3d} shots seed {seed:3d} {cam}: {total_dof} directions; canonical correlations RMS: "
              f"{'; '.join(parts)}; pooled chi2 variance / chi-square's {1 + 2 * rho2 / total_dof:.3f}", flush=True)


def _noise_map(full, half) -> np.ndarray:
    """(n_params, 2 N) the half's parameter change per unit change of each of the full solution's
    residuals (``-(JᵀJ)⁻¹ Jᵀ`` on the half's rows, zero elsewhere): its least-squares image of the noise."""
    rows = np.flatnonzero(np.isin(full.obs.shot, np.unique(half.obs.shot)) & full.inliers)
    J = half.jacobian.toarray()
    out = np.zeros((J.shape[1], 2 * len(full.obs)))
    out[:, (2 * rows[:, None] + np.arange(2)).ravel()] = -np.linalg.solve(J.T @ J, J.T)
    return out


def _canonical_correlations(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Canonical correlations of two linear maps of the same white noise, ``A e`` and ``B e``."""
    La, Lb = np.linalg.cholesky(A @ A.T), np.linalg.cholesky(B @ B.T)
    return np.linalg.svd(np.linalg.solve(La, A @ B.T) @ np.linalg.inv(Lb).T, compute_uv=False)


def caliscope() -> None:
    """Cross-validation and warnings of the real 4-webcam rig calibrated from its rig views alone."""
    from bench_calibration import caliscope_observations

    result = calibrate(caliscope_observations(), charuco((4, 5), 0.054, 0.0405, "DICT_4X4_1000"), "opencv4")
    print("caliscope-4cam-charuco, opencv4, rig views alone:")
    cv = result.cross_validation
    for name, r in cv.cameras.items():
        splits = ", ".join(f"{split} {c[name].ratio:.2f} ({c[name].dof})" for split, c in cv.splits.items()
                           if c[name] is not None)
        print(f"  {name}: pooled whitened ratio {r.ratio:.2f} ({r.dof}), {r.measured_px:.1f}/{r.predicted_px:.1f} px; "
              f"per split: {splits}" if r else f"  {name}: no common area")
    print(f"  {len(result.warnings)} warning lines:")
    for line in result.warnings:
        print(f"  WARNING: {line}")


if __name__ == "__main__":
    main()
