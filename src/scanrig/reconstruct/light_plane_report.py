"""Summary text and residual plot of a light-plane calibration (matplotlib imported inside)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.io.atomic import atomic_write
from scanrig.reconstruct.light_plane_fit import LightPlaneFit


def format_light_plane_summary(fit: LightPlaneFit, camera: str, skipped=()) -> str:
    """The plane (normal, offset, sigmas), per-pose residuals and inliers, skipped images, warnings."""
    plane = fit.plane
    tilt_deg = np.degrees(plane.tilt_sigma_rad())
    n_in = int(fit.inliers.sum())
    lines = [f"light plane of {camera} (world frame of rig.toml): normal . x = offset",
             f"  normal   [{plane.normal[0]:+.6f}, {plane.normal[1]:+.6f}, {plane.normal[2]:+.6f}]"
             f"  sigma (tilt) {tilt_deg[0]:.4f} / {tilt_deg[1]:.4f} deg",
             f"  offset   {1e3 * plane.offset:+.4f} mm  sigma {1e3 * plane.offset_sigma_m():.4f} mm"
             f"  (at the points' centroid {1e3 * plane.offset_sigma(plane.centroid[None])[0]:.4f} mm)",
             f"  inliers  {n_in} of {len(fit.inliers)} stripe points, RMS {1e3 * plane.residual_m:.4f} mm "
             f"(robust scale {1e3 * fit.scale_m:.4f} mm)",
             f"  images   {len(fit.poses)} used, {len(skipped)} skipped",
             f"  {'pose':<16}{'points':>8}{'inliers':>9}{'RMS mm':>10}{'mean mm':>10}"]
    for r in fit.poses:
        lines.append(f"  {r.name:<16}{r.n_points:>8}{r.n_inliers:>9}{1e3 * r.rms_m:>10.4f}{1e3 * r.mean_m:>+10.4f}")
    lines += [f"  skipped: {line}" for line in skipped]
    lines += [f"  warning: {w}" for w in fit.warnings]
    return "\n".join(lines) + "\n"


def write_light_plane_plot(fit: LightPlaneFit, camera: str, path: str | Path) -> Path:
    """``path`` (PNG): each stripe point's distance to the plane along the plane's depth axis,
    coloured by pose (rejected points as grey crosses), and each pose's RMS and inlier share."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plane = fit.plane
    along_mm = 1e3 * (fit.p_world - plane.centroid) @ plane.axes.T
    d_mm = 1e3 * plane.distance(fit.p_world)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    ax = axes[0]
    out = ~fit.inliers
    ax.plot(along_mm[out, 0], d_mm[out], "x", color="0.6", ms=3, label="rejected")
    for k, r in enumerate(fit.poses):
        sel = fit.inliers & (fit.pose_index == k)
        ax.plot(along_mm[sel, 0], d_mm[sel], ".", ms=2, label=r.name)
    limit = 6.0 * 1e3 * max(fit.scale_m, plane.residual_m)
    ax.set(ylim=(-limit, limit), xlabel="position along the plane's first axis (mm)",
           ylabel="distance to the plane (mm)",
           title=f"{camera}: light-plane residuals, RMS {1e3 * plane.residual_m:.3f} mm")
    ax.legend(loc="upper right", fontsize=7, markerscale=4, ncol=2)
    ax = axes[1]
    x = np.arange(len(fit.poses))
    ax.bar(x, [1e3 * r.rms_m for r in fit.poses], color="0.4")
    ax.set_xticks(x, [r.name for r in fit.poses], rotation=45, fontsize=7)
    ax.set(ylabel="inlier RMS (mm)", title="per pose: RMS (bars), inlier share (line)")
    share = ax.twinx()
    share.plot(x, [r.n_inliers / max(r.n_points, 1) for r in fit.poses], "o-", color="C3")
    share.set(ylim=(0, 1.05), ylabel="inliers / points")
    fig.tight_layout()
    path = Path(path)
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=80)
    plt.close(fig)
    return path
