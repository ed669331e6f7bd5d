"""The calibration report: a one-screen text summary, the same as JSON, and the outlier list.

``summary.json`` (docs/file-formats.md) carries per camera its model, parameters and their σ,
RMS, corners used and rejected, projection σ, cross-validation, its corners alone against the rig,
and the warnings, each a single line naming its camera and cause, exactly as printed; for a
flexible target (``flex = true``) also the board's two flex terms and their σ.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from scanrig.calibration.camera_agreement import CAUSES as AGREEMENT_CAUSES
from scanrig.calibration.camera_agreement import P_WARN, agreement_warnings
from scanrig.calibration.cross_validation import CAUSES, RATIO_WARN, cross_validation_warnings
from scanrig.io.atomic import atomic_write, write_text_atomic

#: Version of the ``summary.json`` layout.
SUMMARY_FORMAT_VERSION = 1


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
        poor = unc.poorly_determined[cam.name]
        if poor:
            lines.append("  poorly determined (1 sigma moves the image by): "
                         + ", ".join(f"{p} {px:.2g} px" for p, _, px in poor))
    if b.state.flex_m is not None:
        (cx, cy), (sx, sy) = b.state.flex_m * 1000.0, unc.flex_std_m * 1000.0
        lines += ["", f"board flex (sag at the centre): along x {cx:.4f} ± {sx:.4f} mm, "
                      f"along y {cy:.4f} ± {sy:.4f} mm"]
    cv = result.cross_validation
    lines.append("")
    if cv is None:
        lines.append("cross-validation (halves of the shots): not run (turned off, too few shots per half, or no "
                     "split whose halves can be solved alone)")
    else:
        lines += _cross_validation_lines(cv)
    lines += _agreement_lines(result.camera_agreement)
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


def dropped_view_warnings(dropped_views: list) -> list[str]:
    """One line per camera for the views the initialisation left out.

    Parameters
    ----------
    dropped_views : list of (camera, shot, reason)
    """
    by_camera: dict = {}
    for cam, shot, reason in dropped_views:
        by_camera.setdefault(cam, []).append((shot, reason))
    lines = []
    for cam, views in by_camera.items():
        shown = ", ".join(f"{shot} ({reason})" for shot, reason in views[:3])
        more = f" and {len(views) - 3} more" if len(views) > 3 else ""
        lines.append(f"{cam}: {len(views)} view(s) left out of the initialisation: {shown}{more}")
    return lines


def _cross_validation_lines(cv) -> list[str]:
    """summary.txt's cross-validation lines: per camera the pooled figures and each split's ratio,
    then the likely causes when some split's ratio exceeds RATIO_WARN."""
    lines = [f"cross-validation: halves of the shots calibrated apart, {len(cv.splits) or 1} split(s) pooled "
             f"({', '.join(cv.splits) or 'odd/even'})"]
    for name, r in cv.cameras.items():
        if r is None:
            lines.append(f"cross-validation {name}: no common area")
        elif r.dof == 0:
            lines.append(f"cross-validation {name}: nothing to compare (its intrinsics are held fixed and "
                         f"its pose defines the frame)")
        else:
            per_split = ", ".join(f"{split} {cameras[name].ratio:.2f}" for split, cameras in cv.splits.items()
                                  if cameras[name] is not None)
            detail = f"; per split: {per_split}" if per_split else ""
            lines.append(f"cross-validation {name}: halves differ by RMS {r.measured_px:.3f} px "
                         f"(max {r.max_px:.3f} px); their uncertainty predicts {r.predicted_px:.3f} px "
                         f"(ratio {r.ratio:.2f} over {r.dof} directions{detail})")
    if cross_validation_warnings(cv):
        lines.append(f"a ratio above {RATIO_WARN:g} in any split means the stated uncertainty is too small. "
                     "Likely causes:")
        lines += [f"  - {cause}" for cause in CAUSES]
    return lines


def _agreement_lines(agreement) -> list[str]:
    """summary.txt's lines of each camera's corners alone against the rig (none for one camera)."""
    if not agreement or all(a is None for a in agreement.values()):
        return []
    lines = ["cameras apart: each camera's corners with target poses of its own, against the rig's shared poses"]
    for name, a in agreement.items():
        lines.append(f"cameras apart {name}: " + ("shares no shot with another camera" if a is None else
                     f"RMS {a.rms_alone_px:.3f} px alone, {a.rms_rig_px:.3f} px in the rig (ratio {a.ratio:.2f} "
                     f"over {a.dof:.0f} constraints, chance {a.p_value:.2g}; 1 when the cameras agree)"))
    if agreement_warnings(agreement):
        lines.append(f"a chance below {P_WARN:g} means the cameras saw the target in different places in one "
                     "shot. Likely causes:")
        lines += [f"  - {cause}" for cause in AGREEMENT_CAUSES]
    return lines


def summary_dict(result) -> dict:
    """The content of ``summary.json`` (docs/file-formats.md): plain JSON types only."""
    b, unc, cv = result.bundle, result.uncertainty, result.cross_validation
    obs = b.obs
    outliers = [o.camera for o in b.outliers]
    cameras = []
    for c, cam in enumerate(result.rig.cameras):
        sig = result.projection_sigma_px[cam.name]
        check = None if cv is None else cv.cameras.get(cam.name)
        cameras.append({
            "name": cam.name,
            "model": cam.model,
            "width": cam.width,
            "height": cam.height,
            "param_names": list(cam.param_names),
            "params": [float(v) for v in cam.params],
            "params_std": [float(v) for v in unc.params_std[cam.name]],
            "rms_px": b.rms_px(c),
            "n_observations": int(np.count_nonzero((obs.camera == c) & b.inliers)),
            "n_outliers": outliers.count(cam.name),
            "n_views": len(np.unique(obs.shot[obs.camera == c])),
            "center_std_m": [float(v) for v in unc.center_std_m[cam.name]],
            "rotation_std_deg": float(unc.rotation_std_deg[cam.name]),
            "poorly_determined": [{"param": p, "std": s, "moved_px": px}
                                  for p, s, px in unc.poorly_determined[cam.name]],
            "projection_sigma_px": {"depth_m": float(result.working_distance_m[cam.name]),
                                    "median": float(np.nanmedian(sig)), "max": float(np.nanmax(sig))},
            "cross_validation": None if check is None else {
                **_check_dict(check),
                "splits": {split: None if cameras[cam.name] is None else _check_dict(cameras[cam.name])
                           for split, cameras in cv.splits.items()}},
            "camera_agreement": _agreement_dict((result.camera_agreement or {}).get(cam.name)),
        })
    out = {
        "format_version": SUMMARY_FORMAT_VERSION,
        "target_kind": result.target.kind,
        "n_shots": len(obs.shot_names),
        "world_frame": f"target frame at shot {obs.shot_names[result.init.reference_shot]!r}",
        "rms_px": b.rms_px(),
        "sigma_px": float(b.sigma_px),
        "n_observations": int(b.inliers.sum()),
        "n_outliers": len(b.outliers),
        "cross_validation_reference_camera": None if cv is None else cv.reference_camera,
        "cameras": cameras,
        "warnings": list(result.warnings),
    }
    if b.state.flex_m is not None:
        out["board_flex_m"] = [float(v) for v in b.state.flex_m]
        out["board_flex_std_m"] = [float(v) for v in unc.flex_std_m]
    return out


def _check_dict(check) -> dict:
    """One camera's cross-validation figures (pooled, or of one split) as JSON."""
    return {"measured_px": check.measured_px, "predicted_px": check.predicted_px, "ratio": check.ratio,
            "dof": check.dof, "max_px": check.max_px, "n_points": check.n_points}


def _agreement_dict(agreement) -> dict | None:
    """One camera's corners alone against the rig as JSON (None when not checked)."""
    if agreement is None:
        return None
    return {"rms_alone_px": agreement.rms_alone_px, "rms_rig_px": agreement.rms_rig_px, "ratio": agreement.ratio,
            "dof": agreement.dof, "p_value": agreement.p_value}


def write_summary_json(result, path: str | Path) -> None:
    """Write :func:`summary_dict` to ``path`` atomically (NaN written as null)."""
    text = json.dumps(_finite(summary_dict(result)), indent=2, allow_nan=False, ensure_ascii=False)
    write_text_atomic(path, text + "\n")


def _finite(value):
    """``value`` with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value
