"""The report's figures, each returned as a PNG ``data:`` URI (the page embeds it; no file, no network).

matplotlib is imported inside each function (Agg backend), so importing this module is cheap.
Calibration plots are not drawn here: the calibration run writes them
(``calibration_report/residuals_<camera>.png``) and the report embeds those files.
"""

from __future__ import annotations

import base64
import io

import numpy as np

#: Resolution of the embedded PNGs.
DPI = 90
#: Bins of histograms.
HIST_BINS = 60
#: Hexagonal cells across the sampling-density map.
DENSITY_CELLS = 45


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def data_uri(png: bytes) -> str:
    """``data:image/png;base64,...`` of PNG bytes."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def figure_uri(fig) -> str:
    """Render a matplotlib figure to a PNG data URI and close it."""
    plt = _pyplot()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return data_uri(buf.getvalue())


def image_uri(rgb: np.ndarray) -> str:
    """A ``(H, W, 3)`` uint8 RGB image as a PNG data URI (lossless)."""
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[:, :, ::-1]))
    if not ok:
        raise ValueError("cannot encode the image as PNG")
    return data_uri(buf.tobytes())


def histogram_figure(values: np.ndarray, xlabel: str, title: str, marker: float | None = None,
                     marker_label: str = "", log: bool = True) -> str:
    """A histogram of finite ``values`` (already in display units), with an optional vertical marker."""
    plt = _pyplot()
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    ax.hist(values, bins=HIST_BINS, log=log, color="tab:blue")
    if marker is not None:
        ax.axvline(marker, color="tab:red", ls="--", label=marker_label)
        ax.legend()
    ax.set_xlabel(xlabel)
    ax.set_ylabel("points")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return figure_uri(fig)


def density_figure(p_world: np.ndarray, spacing_m: np.ndarray) -> str:
    """Sampling-density map: points per cell over the cloud seen along its smallest principal axis.

    Parameters
    ----------
    p_world : (N, 3) float array
        Points, metres.
    spacing_m : (N,) float array
        Nearest-neighbour spacing at each point, metres (histogram panel).

    Returns
    -------
    str
        PNG data URI with the map (points per hexagonal cell of ``DENSITY_CELLS`` across) and the
        spacing histogram.
    """
    plt = _pyplot()
    centred = p_world - p_world.mean(axis=0)
    _, _, axes_t = np.linalg.svd(centred[:: max(1, len(centred) // 20000)], full_matrices=False)
    plane_mm = centred @ axes_t[:2].T * 1e3
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 4.2), gridspec_kw={"width_ratios": [1.4, 1]})
    # A square extent: points on a line (one stripe) would otherwise give a degenerate axis.
    lo, hi = plane_mm.min(axis=0), plane_mm.max(axis=0)
    half = max(float(np.max(hi - lo)), 1e-3) / 2
    mid = (lo + hi) / 2
    hb = ax0.hexbin(plane_mm[:, 0], plane_mm[:, 1], gridsize=DENSITY_CELLS, cmap="viridis", mincnt=1,
                    extent=(mid[0] - half, mid[0] + half, mid[1] - half, mid[1] + half))
    fig.colorbar(hb, ax=ax0, label=f"points per cell (cells ~{2 * half / DENSITY_CELLS:.2g} mm across)")
    ax0.set_aspect("equal")
    ax0.set_xlabel("first principal axis (mm)")
    ax0.set_ylabel("second principal axis (mm)")
    ax0.set_title("sampling density (projected on the cloud's main plane)", fontsize=10)
    ax1.hist(spacing_m * 1e3, bins=HIST_BINS, color="tab:green")
    ax1.set_xlabel("local spacing (mm)")
    ax1.set_ylabel("points")
    ax1.set_title(f"median {np.median(spacing_m) * 1e3:.3f} mm", fontsize=10)
    fig.tight_layout()
    return figure_uri(fig)
