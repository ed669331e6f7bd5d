"""Residual and uncertainty plots per camera (PNG, headless; matplotlib imported inside)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.io.atomic import atomic_write


def write_plots(result, folder: str | Path) -> list[Path]:
    """For each camera ``residuals_<cam>.png``: residual vectors over the image (scaled),
    histogram of residual lengths, detection coverage, and the projection-uncertainty map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    b = result.bundle
    written = []
    for c, cam in enumerate(result.rig.cameras):
        rows = b.obs.camera == c
        uv, res, inl = b.obs.uv[rows], b.residuals_px[rows], b.inliers[rows]
        fig, axes = plt.subplots(2, 2, figsize=(12, 9))
        ax = axes[0, 0]
        norm = np.linalg.norm(res, axis=1)
        scale = 0.05 * max(cam.width, cam.height) / max(np.nanpercentile(norm[inl], 95), 1e-9)
        ax.quiver(uv[inl, 0], uv[inl, 1], res[inl, 0] * scale, res[inl, 1] * scale, norm[inl],
                  angles="xy", scale_units="xy", scale=1, cmap="viridis", width=0.002)
        if np.any(~inl):
            ax.plot(uv[~inl, 0], uv[~inl, 1], "rx", label="outliers")
            ax.legend(loc="upper right")
        ax.set(xlim=(0, cam.width), ylim=(cam.height, 0), aspect="equal",
               title=f"{cam.name}: residuals (x{scale:.0f})", xlabel="u (px)", ylabel="v (px)")
        ax = axes[0, 1]
        ax.hist(norm[inl], bins=50, color="0.4")
        ax.set(title=f"residual length: RMS {b.rms_px(c):.3f} px", xlabel="px", ylabel="count")
        ax = axes[1, 0]
        ax.hist2d(uv[:, 0], uv[:, 1], bins=(16, 12), range=[[0, cam.width], [0, cam.height]], cmap="Greys")
        ax.set(xlim=(0, cam.width), ylim=(cam.height, 0), aspect="equal", title="coverage (detections)")
        ax = axes[1, 1]
        from scanrig.calibration.uncertainty import MAP_SAMPLES, image_grid

        sigma = result.projection_sigma_px[cam.name].reshape(MAP_SAMPLES[1], MAP_SAMPLES[0])
        q = image_grid(cam)
        im = ax.imshow(sigma, extent=(q[:, 0].min(), q[:, 0].max(), q[:, 1].max(), q[:, 1].min()), cmap="magma")
        fig.colorbar(im, ax=ax, label="px")
        ax.set(title=f"projection sigma at {result.working_distance_m[cam.name]:.2f} m", aspect="equal")
        fig.tight_layout()
        path = folder / f"residuals_{cam.name}.png"
        with atomic_write(path, "wb") as f:
            fig.savefig(f, format="png", dpi=80)
        plt.close(fig)
        written.append(path)
    return written
