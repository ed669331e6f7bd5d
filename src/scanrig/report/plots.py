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
#: A distance histogram's axis ends at this percentile of the data times AXIS_MARGIN.
AXIS_PERCENTILE = 99.9
AXIS_MARGIN = 1.2


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


def fitted_top(values: np.ndarray) -> float:
    """End of a histogram axis fitted to non-negative ``values``: their AXIS_PERCENTILE times AXIS_MARGIN."""
    return max(float(np.percentile(values, AXIS_PERCENTILE)), 1e-6) * AXIS_MARGIN if len(values) else 1.0


def distance_histogram(distance_mm: np.ndarray, outlier_mm: float) -> str:
    """Histogram of distances to the truth on an axis fitted to the data (0 to its 99.9th percentile).

    The few points beyond the axis are counted in the title, not stretched over it; the outlier
    threshold is drawn only when it falls on the axis.
    """
    plt = _pyplot()
    d = np.asarray(distance_mm, np.float64)
    d = d[np.isfinite(d)]
    top = fitted_top(d)
    beyond = int(np.count_nonzero(d > top))
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    ax.hist(np.minimum(d, top), bins=HIST_BINS, range=(0.0, top), log=True, color="tab:blue")
    if outlier_mm <= top:
        ax.axvline(outlier_mm, color="tab:red", ls="--", label=f"{outlier_mm:g} mm")
        ax.legend()
    ax.set_xlim(0.0, top)
    ax.set_xlabel("distance to the true surface (mm)")
    ax.set_ylabel("points")
    rms = float(np.sqrt(np.mean(d**2))) if d.size else float("nan")
    extra = f"; {beyond} beyond the axis (max {d.max():.3g} mm), counted in the last bin" if beyond else ""
    ax.set_title(f"all {d.size} points, RMS {rms:.4f} mm{extra}", fontsize=9)
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
    spacing_mm = spacing_m * 1e3
    top = fitted_top(spacing_mm)
    beyond = int(np.count_nonzero(spacing_mm > top))
    ax1.hist(np.minimum(spacing_mm, top), bins=HIST_BINS, range=(0.0, top), color="tab:green")
    ax1.set_xlim(0.0, top)
    ax1.set_xlabel("local spacing (mm)")
    ax1.set_ylabel("points")
    extra = f"; {beyond} beyond the axis, in the last bin" if beyond else ""
    ax1.set_title(f"median {np.median(spacing_m) * 1e3:.3f} mm{extra}", fontsize=10)
    fig.tight_layout()
    return figure_uri(fig)
