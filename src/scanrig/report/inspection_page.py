"""``inspection.html``: the deviation map of a scan against its CAD model, one self-contained page.

Lives in the report layer (which may import :mod:`scanrig.inspect`, not the other way round) so
that it reuses the report's page, figures and interactive 3-D viewer. Sections: the verdict, the
deviation map (three views in the diverging colour of ``inspection.ply``, and the interactive
viewer), the histogram, the statistics, the worst regions by position, the alignment.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.inspect.inspection import Inspection
from scanrig.inspect.outputs import (
    COLOUR_MAP,
    COLOUR_SPAN_TOLERANCES,
    HTML_NAME,
    WRITTEN_BY,
    check_outputs_free,
)
from scanrig.io.atomic import write_text_atomic
from scanrig.report import plots
from scanrig.report.html import Section, page
from scanrig.report.viewer import MAX_VIEWER_POINTS, subsample, viewer_html

#: Points drawn in the static views.
VIEW_POINTS = 60_000
#: The histogram's axis spans this many tolerances either side of 0.
HIST_SPAN_TOLERANCES = 4.0
#: The static views: (title, horizontal axis, vertical axis, depth axis, +1 when the viewer looks
#: from its positive side).
VIEWS = (("top (looking along -z)", 0, 1, 2, 1), ("front (looking along +y)", 0, 2, 1, -1),
         ("side (looking along -x)", 1, 2, 0, 1))


def inspection_html(inspection: Inspection, points_m: np.ndarray, title: str, rng: np.random.Generator) -> str:
    """The whole ``inspection.html`` document.

    Parameters
    ----------
    inspection : Inspection
        The result.
    points_m : (N, 3) float array
        The cloud given to ``inspect_cloud`` (cloud frame, metres).
    title : str
        Page title.
    rng : numpy.random.Generator
        Draws the subsamples shown.
    """
    stats, tol_mm = inspection.stats, 1e3 * inspection.stats.tolerance_m
    p = inspection.points_cad(np.asarray(points_m, np.float64))
    dev_mm = 1e3 * inspection.deviation_m
    verdict = Section("Verdict")
    verdict.text(f"{stats.n_points} points compared with the CAD model: {100 * stats.within_tolerance:.1f} % within "
                 f"±{tol_mm:.3g} mm; RMS deviation {1e3 * stats.rms_m:.4f} mm, mean {1e3 * stats.mean_m:+.4f} mm, "
                 f"95 % of |deviation| below {1e3 * stats.p95_abs_m:.4f} mm, largest {1e3 * stats.max_abs_m:.4f} mm.")
    verdict.text(_alignment_line(inspection))
    for warning in inspection.warnings:
        verdict.text(f"Warning: {warning}")
    sign = ("signed: positive outside the material (a bump), negative inside (a dent)" if inspection.signed
            else "unsigned (the CAD mesh is not closed)")
    verdict.note(f"written by {WRITTEN_BY}; deviation is {sign}; coordinates in the CAD frame.")

    view = Section("Deviation map")
    view.image(_views_uri(p, dev_mm, tol_mm, rng), "deviation seen from three sides")
    view.note(f"Colour: {COLOUR_MAP}, from -{COLOUR_SPAN_TOLERANCES * tol_mm:.3g} mm (blue, inside) to "
              f"+{COLOUR_SPAN_TOLERANCES * tol_mm:.3g} mm (red, outside); white is on the surface. Below, the "
              "interactive view: its colours run over the 1st-99th percentile of the field shown, so the "
              "first field is clipped at the same ±2 tolerances (outliers would otherwise stretch the scale).")
    keep = subsample(len(p), MAX_VIEWER_POINTS, rng)
    span_mm = COLOUR_SPAN_TOLERANCES * tol_mm
    fields = [(f"deviation, clipped at ±{span_mm:.3g} mm", "mm", np.clip(dev_mm[keep], -span_mm, span_mm)),
              ("deviation", "mm", dev_mm[keep]), ("|deviation| / tolerance", "", np.abs(dev_mm[keep]) / tol_mm)]
    view.raw(viewer_html(p[keep], fields, "inspection"))

    hist = Section("Histogram")
    hist.image(_histogram_uri(dev_mm, tol_mm, inspection.signed), "histogram of the deviations")

    table = Section("Statistics")
    table.table(["quantity", "value"], [
        ["points", stats.n_points], ["RMS deviation (mm)", 1e3 * stats.rms_m],
        ["mean deviation (mm)", 1e3 * stats.mean_m], ["95th percentile of |deviation| (mm)", 1e3 * stats.p95_abs_m],
        ["largest |deviation| (mm)", 1e3 * stats.max_abs_m],
        ["tolerance (mm)", tol_mm], ["within tolerance (%)", 100 * stats.within_tolerance]])

    regions = Section("Worst regions")
    if inspection.regions:
        regions.table(["#", "kind", "side", "centre x (mm)", "centre y (mm)", "centre z (mm)", "peak (mm)",
                       "mean (mm)", "radius (mm)", "points"],
                      [[i + 1, _kind(r.mean_m, inspection.signed), r.facing or "-", *(1e3 * r.centroid_m).tolist(),
                        1e3 * r.peak_m, 1e3 * r.mean_m, 1e3 * r.radius_m, r.n_points]
                       for i, r in enumerate(inspection.regions)])
        regions.note("Out-of-tolerance points joined by proximity, worst peak first; centre in the CAD frame; "
                     "side: the CAD axes the surface there faces (+z: a face looking up +z).")
    else:
        regions.text("No region of out-of-tolerance points.")

    align = Section("Alignment")
    align.text(_alignment_line(inspection))
    align.pre("cad_from_cloud (metres):\n" + "\n".join(" ".join(f"{v: .9f}" for v in row)
                                                       for row in inspection.cad_from_cloud))
    return page(title, [verdict, view, hist, table, regions, align])


def _kind(mean_m: float, signed: bool) -> str:
    if not signed:
        return "off the surface"
    return "bump (material added)" if mean_m > 0 else "dent (material missing)"


def _alignment_line(inspection: Inspection) -> str:
    a = inspection.alignment
    if a.method == "none":
        return "Alignment: none (the cloud was taken as given in the CAD frame)."
    return (f"Alignment: {a.method}; residual {1e3 * a.residual_rms_m:.4f} mm RMS on the "
            f"{100 * a.inlier_fraction:.1f} % of the points the fit kept ({a.iterations} iterations).")


def _views_uri(p_cad_m: np.ndarray, dev_mm: np.ndarray, tol_mm: float, rng: np.random.Generator) -> str:
    """Three orthographic views of the points (CAD frame, metres), coloured by deviation (mm)."""
    plt = plots._pyplot()
    keep = subsample(len(p_cad_m), VIEW_POINTS, rng)
    p, d = 1e3 * p_cad_m[keep], dev_mm[keep]
    span = COLOUR_SPAN_TOLERANCES * tol_mm
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    for ax, (name, h, v, depth, side) in zip(axes, VIEWS):
        order = np.argsort(side * p[:, depth])                         # far points first, near on top
        art = ax.scatter(p[order, h], p[order, v], c=d[order], s=1.0, cmap=COLOUR_MAP, vmin=-span, vmax=span,
                         rasterized=True, linewidths=0)
        ax.set_aspect("equal")
        ax.set_xlabel(f"{'xyz'[h]} (mm)")
        ax.set_ylabel(f"{'xyz'[v]} (mm)")
        ax.set_title(name, fontsize=10)
    fig.colorbar(art, ax=axes, label="deviation (mm)", shrink=0.9)
    return plots.figure_uri(fig)


def _histogram_uri(dev_mm: np.ndarray, tol_mm: float, signed: bool) -> str:
    """Histogram of the deviations (mm) over ±:data:`HIST_SPAN_TOLERANCES` tolerances, the
    tolerance band dashed; deviations beyond are counted in the end bins (and in the title)."""
    plt = plots._pyplot()
    top = HIST_SPAN_TOLERANCES * tol_mm
    lo = -top if signed else 0.0
    beyond = int(np.count_nonzero((dev_mm > top) | (dev_mm < lo)))
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    ax.hist(np.clip(dev_mm, lo, top), bins=plots.HIST_BINS, range=(lo, top), log=True, color="tab:blue")
    for x in ((-tol_mm, tol_mm) if signed else (tol_mm,)):
        ax.axvline(x, color="tab:red", ls="--")
    ax.set_xlim(lo, top)
    ax.set_xlabel("deviation (mm)" + ("; positive outside the material" if signed else ", unsigned"))
    ax.set_ylabel("points")
    ax.set_title(f"{len(dev_mm)} points; dashed: tolerance ±{tol_mm:.3g} mm; {beyond} beyond the axis, "
                 "counted in the end bins", fontsize=9)
    fig.tight_layout()
    return plots.figure_uri(fig)


def write_inspection_page(inspection: Inspection, out_dir: Path, *, points_m: np.ndarray, title: str) -> Path:
    """Write ``out_dir/inspection.html`` atomically (refusing a file that scanrig inspect did not write).

    Returns
    -------
    Path
        The page.
    """
    out_dir = Path(out_dir)
    check_outputs_free(out_dir, (HTML_NAME,))
    out_dir.mkdir(parents=True, exist_ok=True)
    document = inspection_html(inspection, points_m, title, np.random.default_rng(inspection.seed))
    write_text_atomic(out_dir / HTML_NAME, document)
    return out_dir / HTML_NAME
