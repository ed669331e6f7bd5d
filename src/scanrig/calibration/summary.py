"""A one-screen text summary of a calibration, and the outlier list."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from scanrig.io.atomic import atomic_write


def format_summary(result) -> str:
    """Plain text: per camera RMS, intrinsics ± sigma, pose sigma; outliers; warnings; cross-validation."""
    b, unc = result.bundle, result.uncertainty
    obs = b.obs
    lines = [f"scanrig calibration: {len(result.rig)} camera(s), {len(obs.shot_names)} shot(s), "
             f"target {result.target.kind}",
             f"observations {int(b.inliers.sum())} used, {len(b.outliers)} rejected as outliers; "
             f"RMS {b.rms_px():.4f} px, residual sigma {b.sigma_px:.4f} px",
             f"world frame: target frame at shot {obs.shot_names[result.init.reference_shot]!r}", ""]
    for c, cam in enumerate(result.rig.cameras):
        std = unc.params_std[cam.name]
        n = int(np.count_nonzero((obs.camera == c) & b.inliers))
        views = len(np.unique(obs.shot[obs.camera == c]))
        sig = result.projection_sigma_px[cam.name]
        lines.append(f"{cam.name} ({cam.model}, {cam.width}x{cam.height}): RMS {b.rms_px(c):.4f} px, "
                     f"{n} points in {views} views")
        lines.append("  " + "  ".join(f"{p}={v:.6g}±{s:.2g}" for p, v, s in zip(cam.param_names, cam.params, std)))
        centre = cam.center_world
        cstd = unc.center_std_m[cam.name] * 1000.0
        lines.append(f"  centre (m) [{centre[0]:.5f}, {centre[1]:.5f}, {centre[2]:.5f}] "
                     f"± [{cstd[0]:.3f}, {cstd[1]:.3f}, {cstd[2]:.3f}] mm; rotation ± "
                     f"{unc.rotation_std_deg[cam.name]:.4f}°")
        lines.append(f"  projection uncertainty at {result.working_distance_m[cam.name]:.3f} m: "
                     f"median {np.nanmedian(sig):.3f} px, worst {np.nanmax(sig):.3f} px")
    cv = result.cross_validation
    lines.append("")
    if cv is None:
        lines.append("cross-validation (odd/even shots): not run (too few shots per half)")
    else:
        for name in result.rig.names:
            lines.append(f"cross-validation {name}: odd/even halves differ by RMS {cv.diff_rms_px[name]:.3f} px "
                         f"(max {cv.diff_max_px[name]:.3f} px); uncertainty predicts ~{cv.expected_rms_px[name]:.3f} px")
    if result.not_found:
        lines.append(f"target not found in {len(result.not_found)} image(s): "
                     + ", ".join(f"{c}/{s}" for c, s in result.not_found[:10])
                     + (" ..." if len(result.not_found) > 10 else ""))
    if b.outliers:
        worst = sorted(b.outliers, key=lambda o: -o.residual_px)[:5]
        lines.append("worst outliers: " + ", ".join(f"{o.camera}/{o.shot} point {o.point_id} ({o.residual_px:.2f} px)"
                                                    for o in worst))
    for w in result.warnings:
        lines.append(f"WARNING: {w}")
    return "\n".join(lines) + "\n"


def write_outliers_csv(result, path: str | Path) -> None:
    """Every rejected observation: camera, image, point id, residual (px)."""
    with atomic_write(path, "w") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(["camera", "image", "point_id", "residual_px"])
        for o in result.bundle.outliers:
            writer.writerow([o.camera, o.shot, o.point_id, f"{o.residual_px:.4f}"])
