"""The report's cloud: the first screen (verdict beside the 3-D view), sampling density, accuracy.

The verdict says what was scanned, how many points, their accuracy against the truth with the
one definition of :mod:`scanrig.reconstruct.evaluate` (RMS distance of all points to the true
surface, before and after the filter, with the count it removed) and the coverage; the same
figures as ``scanrig evaluate SESSION``. The 3-D view shows the filter's mesh with the points
coloured by their distance to the true surface.
"""

from __future__ import annotations

import html
from dataclasses import dataclass

import numpy as np

from scanrig.io.object_poses import OBJECT_FRAME_NOTE
from scanrig.io.session import Session
from scanrig.reconstruct.evaluate import COVERAGE_DISTANCE_M
from scanrig.report import plots
from scanrig.report.html import Section
from scanrig.report.viewer import MAX_VIEWER_TRIANGLES, subsample, viewer_html

#: Fewest points for a sampling-density map (fewer span no area: the map's axes would be degenerate).
MIN_DENSITY_POINTS = 10
#: Folder of the inspection against CAD in a session (``scanrig demo`` writes it; ``scanrig inspect --out``).
INSPECTION_DIR = "inspection"
#: Size of the first screen's 3-D view: with the title and the verdict beside it, it fits a
#: 1280 x 800 window.
FIRST_VIEW_PX = (800, 520)


@dataclass
class CloudData:
    """What the cloud sections share: the cloud, its spacing and its accuracy (None without truth)."""

    cloud: object
    comments: list
    spacing_m: np.ndarray
    accuracy: object | None


def load_cloud(session: Session) -> CloudData | None:
    """``points.ply`` with its local spacing and its accuracy, or None without a cloud of 2 points or more."""
    from scipy.spatial import cKDTree

    from scanrig.reconstruct.evaluate import session_accuracy
    from scanrig.reconstruct.points import read_points

    if not session.points_path.is_file():
        return None
    cloud, comments = read_points(session.points_path)
    if len(cloud) < 2:
        return None
    # Nearest-neighbour spacing, scaled like scanrig.scan.coverage.local_spacing (sqrt(2) d).
    d, _ = cKDTree(cloud.p_world).query(cloud.p_world, k=2)
    accuracy = None
    if (session.truth_dir / "meshes").is_dir():   # as `scanrig evaluate SESSION`: the cloud as it is
        accuracy = session_accuracy(session.points_path, session.truth_dir, surface_path=session.root / "surface.ply")
    return CloudData(cloud, comments, np.sqrt(2.0) * d[:, 1], accuracy)


def first_screen(session: Session, data: CloudData | None, facts: list, subject: str, rng: np.random.Generator,
                 max_points: int) -> Section:
    """The verdict beside the 3-D view of the mesh and the points."""
    sec = Section("Verdict")
    if data is None:
        n = 0
        if session.points_path.is_file():
            from scanrig.io.ply import read_ply

            n = len(read_ply(session.points_path)[0]["x"])
        sec.note(f"Scanned: {subject}. " + (f"points.ply holds {n} point(s): nothing to show." if n
                                            else "points.ply not found: nothing reconstructed yet (scanrig reconstruct)."))
        return sec
    cloud, acc = data.cloud, data.accuracy
    facts.append(("points", str(len(cloud))))
    lines = [("Scanned", subject),
             ("Points", f"{len(cloud)} in {len(np.unique(cloud.frame))} frames")]
    if acc is not None:
        b = acc.before
        lines.append(("Accuracy against the truth",
                      (f"RMS {b['rms_m'] * 1e3:.4f} mm: the RMS of the distances of all {b['n_points']} points to "
                       f"the true surface ({100 * b['fraction_beyond']:.2f} % beyond {b['outlier_m'] * 1e3:g} mm).")))
        if acc.after is not None:
            subset = (f" It was given {acc.n_filter_input} of the {b['n_points']} points, drawn at random."
                      if acc.n_filter_input != b["n_points"] else "")
            lines.append(("After the filter", (f"RMS {acc.after['rms_m'] * 1e3:.4f} mm over the "
                                               f"{acc.after['n_points']} points it kept; it removed {acc.n_removed}."
                                               f"{subset}")))
        else:
            lines.append(("After the filter", acc.surface_note or "not filtered (scanrig filter)"))
        lines.append(("Coverage", (f"{100 * acc.coverage:.1f} % of the true surface in the cloud's bounding box lies "
                                   f"within {COVERAGE_DISTANCE_M * 1e3:g} mm of a point (surfaces no camera sees count "
                                   "as uncovered).")))
        lines.append(("Same figures", f"scanrig evaluate {session.root.name}"))
    else:
        sigma = cloud.sigma[np.isfinite(cloud.sigma)]
        lines.append(("Accuracy", "no ground truth (truth/meshes) in this session: it cannot be measured here"
                                  + (f"; the points' predicted 1-sigma has median {np.median(sigma) * 1e3:.4f} mm."
                                     if len(sigma) else ".")))
    for label, value in [f for f in facts if f[0] == "calibration RMS reprojection error"]:
        lines.append(("Calibration", f"RMS reprojection error {value}"))
    verdict = "".join(f"<dt>{html.escape(k)}</dt><dd>{html.escape(v)}</dd>" for k, v in lines)
    sec.raw(f'<div class="first-screen">{_viewer(session, data, rng, max_points)}'
            f'<dl class="verdict">{verdict}</dl></div>')
    return sec


def _viewer(session: Session, data: CloudData, rng: np.random.Generator, max_points: int) -> str:
    from scanrig.io.ply import read_ply

    cloud, acc = data.cloud, data.accuracy
    fields = [] if acc is None else [("distance to true surface", "mm", acc.distance_m * 1e3)]
    deviation = _inspection_deviation(session, len(cloud))
    if deviation is not None:
        fields.append(("deviation from CAD (inspection)", "mm", deviation * 1e3))
    fields += [("uncertainty (1-sigma, largest axis)", "mm", cloud.sigma * 1e3),
               ("reprojection residual", "px", cloud.residual_px), ("local spacing", "mm", data.spacing_m * 1e3),
               ("views", "cameras", cloud.n_views), ("frame", "index", cloud.frame)]
    keep = subsample(len(cloud), max_points, rng)
    mesh, note = None, "no mesh.ply (scanrig filter writes it)"
    mesh_path = session.root / "mesh.ply"
    if mesh_path.is_file():
        vertices, faces, _ = read_ply(mesh_path)
        if faces is not None and len(faces):
            shown = subsample(len(faces), MAX_VIEWER_TRIANGLES, rng)
            mesh = (np.column_stack([vertices[k] for k in ("x", "y", "z")]), faces[shown])
            note = f"the filter's mesh ({len(shown)} of {len(faces)} triangles)"
    frame = OBJECT_FRAME_NOTE if any(OBJECT_FRAME_NOTE in c for c in data.comments) else "world frame of rig.toml"
    caption = (f"{len(keep)} of {len(cloud)} points ({frame}) on {note}; colour scale from the 1st to the 99th "
               "percentile.")
    return (f'<div class="first-view">{viewer_html(cloud.p_world[keep], [(a, u, v[keep]) for a, u, v in fields], mesh=mesh, size_px=FIRST_VIEW_PX)}'
            f'<p class="hint">{html.escape(caption)}</p></div>')


def _inspection_deviation(session: Session, n_points: int) -> np.ndarray | None:
    """``deviation_m`` of ``inspection/inspection.ply`` when it inspected this ``points.ply`` (same count)."""
    from scanrig.io.ply import read_ply

    path = session.root / INSPECTION_DIR / "inspection.ply"
    if not path.is_file():
        return None
    vertices, _, _ = read_ply(path)
    deviation = vertices.get("deviation_m")
    return deviation.astype(np.float64) if deviation is not None and len(deviation) == n_points else None


def inspection_section(session: Session, facts: list) -> list[Section]:
    """The inspection against CAD (``inspection/inspection.json``) with a link to its page, if there is one."""
    import json

    path = session.root / INSPECTION_DIR / "inspection.json"
    if not path.is_file():
        return []
    sec = Section("Inspection against CAD")
    doc = json.loads(path.read_text(encoding="utf-8"))
    tol_mm = doc["tolerance_m"] * 1e3
    facts.append((f"within ±{tol_mm:g} mm of the CAD", f"{100 * doc['within_tolerance']:.1f} %"))
    sec.text(f"{doc.get('title', '')}: the points aligned to the CAD model and the deviation of each (the 3-D "
             "view above colours by it: 'deviation from CAD').")
    a = doc["alignment"]
    sec.table(["quantity", "value"], [
        ["points", doc["n_points"]], ["deviation RMS (mm)", doc["rms_m"] * 1e3], ["mean (mm)", doc["mean_m"] * 1e3],
        ["95 % of |deviation| (mm)", doc["p95_abs_m"] * 1e3], ["max |deviation| (mm)", doc["max_abs_m"] * 1e3],
        [f"within ±{tol_mm:g} mm", f"{100 * doc['within_tolerance']:.1f} %"],
        ["signed", "yes (positive outside the material)" if doc["signed"] else "no (open CAD mesh)"],
        ["alignment", f"{a['method']}, residual {a['residual_rms_m'] * 1e3:.4f} mm on {100 * a['inlier_fraction']:.1f} %"]])
    for warning in doc.get("warnings", []):
        sec.note(warning)
    if (session.root / INSPECTION_DIR / "inspection.html").is_file():
        sec.raw(f'<p>The deviation map, histogram and worst regions: <a href="{INSPECTION_DIR}/inspection.html">'
                f'{INSPECTION_DIR}/inspection.html</a>.</p>')
    return [sec]


def cloud_sections(data: CloudData | None, facts: list) -> list[Section]:
    """Flags, sampling density and accuracy against the truth (nothing without a cloud)."""
    from scanrig.reconstruct.flags import Flag

    if data is None:
        return []
    cloud = data.cloud
    view, density = Section("Point cloud"), Section("Sampling density")
    flag_rows = [[f.name.lower(), int(np.count_nonzero(cloud.flags & f.value))] for f in Flag]
    view.table(["flag", "points"], [["(none)", int(np.count_nonzero(cloud.flags == 0))], *flag_rows])
    if len(cloud) >= MIN_DENSITY_POINTS:
        density.image(plots.density_figure(cloud.p_world, data.spacing_m), "sampling density map")
    else:
        density.note(f"{len(cloud)} points are too few for a density map (at least {MIN_DENSITY_POINTS}).")
    facts.append(("median local spacing", f"{np.median(data.spacing_m) * 1e3:.3f} mm"))
    if data.accuracy is None:
        return [view, density]
    return [view, density, _accuracy_section(data.accuracy, facts)]


def _accuracy_section(acc, facts: list) -> Section:
    sec = Section("Accuracy against truth")
    b = acc.before
    facts.append(("RMS distance to the truth, all points", f"{b['rms_m'] * 1e3:.4f} mm"))
    sec.text("Accuracy is the RMS of the distances of every point of points.ply to the true surface (the union "
             "of truth/meshes), no point set aside; after the filter, the same over the points it kept, at their "
             f"denoised positions. Frame: {acc.alignment}.")
    sec.image(plots.distance_histogram(acc.distance_m * 1e3, b["outlier_m"] * 1e3), "distance histogram")
    rows = [["points.ply (all points)", *_stat_row(b)]]
    if acc.after is not None:
        rows.append([f"kept by the filter ({acc.n_removed} of its {acc.n_filter_input} removed)", *_stat_row(acc.after)])
        facts.append(("RMS distance to the truth, points the filter kept", f"{acc.after['rms_m'] * 1e3:.4f} mm"))
        facts.append(("points the filter removed", str(acc.n_removed)))
    sec.table(["cloud", "points", "RMS (mm)", "mean (mm)", "95 % (mm)", "99 % (mm)", "max (mm)",
               f"beyond {b['outlier_m'] * 1e3:g} mm"], rows)
    facts.append((f"coverage (true surface within {COVERAGE_DISTANCE_M * 1e3:g} mm of a point)",
                  f"{100 * acc.coverage:.1f} %"))
    return sec


def _stat_row(stats: dict) -> list:
    return [stats["n_points"], *(stats[k] * 1e3 for k in ("rms_m", "mean_m", "p95_m", "p99_m", "max_m")),
            f"{stats['fraction_beyond']:.2%}"]
