"""``write_report``: one self-contained ``report.html`` from whatever a session folder holds.

Each section uses the files that exist and says plainly which are missing:

==========================  ======================================================================
section                     reads
==========================  ======================================================================
summary                     everything below, plus the caller's summary rows (e.g. the demo's)
calibration                 ``rig.toml``, ``calibration_report/`` (summary, residual, coverage and
                            projection-uncertainty plots written by ``scanrig calibrate``)
light plane                 ``light_plane.toml``, its summary and residual plots in ``calibration_report/``,
                            ``scan/object_poses.csv`` (only sessions that have one of them)
detection                   ``traces.parquet`` and ``scan/<camera>/<frame>`` images (overlays)
point cloud                 ``points.ply``: interactive 3-D view coloured by error/uncertainty
sampling density            ``points.ply``
accuracy against truth      ``points.ply``, ``surface.ply`` and ``truth/meshes/*.ply``
run                         ``session.toml``, file headers, package versions, the report's seed
==========================  ======================================================================
"""

from __future__ import annotations

import platform
import time
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

from scanrig.io.atomic import write_text_atomic
from scanrig.io.object_poses import OBJECT_FRAME_NOTE
from scanrig.io.session import Session
from scanrig.report import plots
from scanrig.report.html import Section, page
from scanrig.report.light_plane_section import light_plane_sections
from scanrig.report.viewer import MAX_VIEWER_POINTS, subsample, viewer_html

#: Packages whose versions the report records.
VERSIONED = ("scanrig", "numpy", "scipy", "opencv-python-headless", "trimesh", "torch", "matplotlib", "pyarrow")
#: Side of the square crop around a detection in the overlays, pixels.
OVERLAY_CROP_PX = 240
#: Fewest points for a sampling-density map (fewer span no area: the map's axes would be degenerate).
MIN_DENSITY_POINTS = 10
#: Longest metadata value shown in full.
METADATA_CHARS = 300
#: Frames shown as detection overlays.
OVERLAY_FRAMES = 2

Progress = Callable[[str], None]


def write_report(session_root: str | Path, out: str | Path | None = None, *, rng: np.random.Generator,
                 summary: list[tuple[str, str]] | None = None, max_points: int = MAX_VIEWER_POINTS,
                 progress: Progress | None = None) -> Path:
    """Write ``report.html`` for a session.

    Parameters
    ----------
    session_root : str or Path
        Session folder.
    out : str or Path, optional
        Output file (default ``SESSION/report.html``).
    rng : numpy.random.Generator
        Draws the viewer's subsample when the cloud has more than ``max_points`` points.
    summary : list of (str, str), optional
        Extra rows for the summary table (e.g. the demo's stage timings).
    max_points : int
        Most points shipped to the 3-D viewer.
    progress : callable, optional
        Called with the name of each section as it starts.

    Returns
    -------
    Path
        The report file.
    """
    session = Session(session_root)
    out = Path(out) if out is not None else session.root / "report.html"
    progress = progress or (lambda name: None)
    facts: list[tuple[str, str]] = []
    sections = []
    for name, build in (("calibration", _calibration), ("light plane", light_plane_sections),
                        ("detection", _detection), ("point cloud", lambda s, f: _cloud(s, f, rng, max_points)),
                        ("run", _run)):
        progress(name)
        sections += build(session, facts)
    summary_section = Section("Summary")
    summary_section.table(["quantity", "value"], [[k, v] for k, v in [*(summary or []), *facts]])
    html = page(f"scanrig report: {session.root.resolve().name}", [summary_section, *sections])
    write_text_atomic(out, html)
    return out


# --- calibration ------------------------------------------------------------------------------
def _calibration(session: Session, facts: list) -> list[Section]:
    from scanrig.calibration.pipeline import REPORT_DIR
    from scanrig.io.rig_file import load_rig_info

    sec = Section("Calibration")
    if not session.rig_path.is_file():
        sec.note(f"{session.rig_path.name} not found: the session is not calibrated yet (scanrig calibrate).")
        return [sec]
    rig, info, metadata = load_rig_info(session.rig_path)
    rows = []
    for cam in rig.cameras:
        extra = info.get(cam.name, {})
        rows.append([cam.name, cam.model, f"{cam.width}x{cam.height}", *(float(p) for p in cam.params[:4]),
                     float(extra["rms_px"]) if "rms_px" in extra else "", str(extra.get("n_observations", "")),
                     ", ".join(f"{float(v):.3g}" for v in cam.params[4:])])
    sec.table(["camera", "model", "size", "fx (px)", "fy (px)", "cx (px)", "cy (px)", "RMS (px)", "observations",
               "distortion"], rows)
    if metadata:
        sec.table(["rig.toml metadata", "value"], [[str(k), _short(v)] for k, v in metadata.items()])
        if "rms_px" in metadata:
            facts.append(("calibration RMS reprojection error", f"{float(metadata['rms_px']):.4f} px"))
    folder = session.root / REPORT_DIR
    summary = folder / "summary.txt"
    if summary.is_file():
        sec.pre(summary.read_text(encoding="utf-8"))
    pngs = [folder / f"residuals_{name}.png" for name in rig.names if (folder / f"residuals_{name}.png").is_file()]
    if not pngs:
        sec.note(f"{REPORT_DIR}/residuals_<camera>.png not found: no residual, coverage or uncertainty plots "
                 "(scanrig calibrate writes them).")
    else:
        sec.text("Per camera: residual vectors (projected minus detected, exaggerated), their histogram, where "
                 "the target points fell in the image, and the 1-sigma uncertainty of projecting a world point "
                 "at the working distance through the calibrated camera.")
    for path in pngs:
        sec.image(plots.data_uri(path.read_bytes()), f"calibration diagnostics: {path.name}")
    return [sec]


# --- detection --------------------------------------------------------------------------------
def _detection(session: Session, facts: list) -> list[Section]:
    from scanrig.laser.traces import read_traces

    sec = Section("Laser detection")
    if not session.traces_path.is_file():
        sec.note("traces.parquet not found: no detections yet (scanrig detect).")
        return [sec]
    table, metadata = read_traces(session.traces_path)
    cams = np.asarray(table.column("camera").to_pylist())
    frames = np.asarray(table.column("frame").to_pylist())
    rank = table.column("rank").to_numpy()
    snr, sigma = table.column("snr").to_numpy(), table.column("sigma_px").to_numpy()
    rows = []
    for cam in dict.fromkeys(cams.tolist()):   # in order of appearance (the session's camera order)
        m = cams == cam
        best = m & (rank == 0)
        medians = [float(np.median(x[best])) if best.any() else "" for x in (snr, sigma)]
        rows.append([cam, len(set(frames[m].tolist())), int(m.sum()), int((m & (rank > 0)).sum()), *medians])
    sec.table(["camera", "frames with a trace", "candidates", "secondary candidates", "median SNR (rank 0)",
               "median sigma (px, rank 0)"], rows)
    facts.append(("laser candidates", f"{table.num_rows} in {len(set(frames.tolist()))} frames"))
    if metadata:
        sec.table(["traces.parquet metadata", "value"], [[str(k), _short(v)] for k, v in metadata.items()])
    if (session.root / "scan").is_dir():
        gallery = _overlays(session, table, cams, frames, rank)
        if gallery:
            sec.text("Detections drawn on the frames (crops): rank-0 candidates green, others orange.")
            sec.gallery(gallery)
    return [sec]


def _overlays(session: Session, table, cams, frames, rank) -> list[tuple[str, str]]:
    import pyarrow.compute as pc

    from scanrig.io.session import read_image
    from scanrig.laser.overlay import render_overlay

    first = table.filter(pc.equal(table.column("rank"), 0))
    seen = first.group_by("frame").aggregate([("camera", "count_distinct")]).sort_by(
        [("camera_count_distinct", "descending"), ("frame", "ascending")])
    ranked = seen.column("frame").to_pylist()      # frames whose laser most cameras found first
    images = {cam: session.image_paths("scan", cam) for cam in session.camera_names("scan")}
    items = []
    for frame in ranked[:OVERLAY_FRAMES]:
        for cam, paths in images.items():
            path = paths.get(frame)
            mask = (frames == frame) & (cams == cam)
            if path is None or not mask.any():
                continue
            rows = table.filter(pc.and_(pc.equal(table.column("frame"), frame), pc.equal(table.column("camera"), cam)))
            rgb = render_overlay(read_image(path), rows)
            best = mask & (rank == 0)
            u = np.median(table.column("u").to_numpy()[best if best.any() else mask])
            v = np.median(table.column("v").to_numpy()[best if best.any() else mask])
            h, w = rgb.shape[:2]
            half = OVERLAY_CROP_PX // 2
            u0 = int(np.clip(round(u) - half, 0, max(w - OVERLAY_CROP_PX, 0)))
            v0 = int(np.clip(round(v) - half, 0, max(h - OVERLAY_CROP_PX, 0)))
            crop = rgb[v0:v0 + OVERLAY_CROP_PX, u0:u0 + OVERLAY_CROP_PX]
            items.append((plots.image_uri(crop), f"frame {frame}, {cam} (crop at u={u0}, v={v0}; "
                                                 f"{int(mask.sum())} candidates)"))
    return items


# --- point cloud, density, accuracy ---------------------------------------------------------------
def _cloud(session: Session, facts: list, rng: np.random.Generator, max_points: int) -> list[Section]:
    from scipy.spatial import cKDTree

    from scanrig.reconstruct.flags import Flag
    from scanrig.reconstruct.points import read_points

    view, density, accuracy = Section("Point cloud"), Section("Sampling density"), Section("Accuracy against truth")
    if not session.points_path.is_file():
        view.note("points.ply not found: nothing reconstructed yet (scanrig reconstruct).")
        return [view]
    cloud, comments = read_points(session.points_path)
    n = len(cloud)
    facts.append(("points", str(n)))
    frame = OBJECT_FRAME_NOTE if any(OBJECT_FRAME_NOTE in c for c in comments) else "world frame of rig.toml"
    if n < 2:
        view.note(f"points.ply holds {n} point(s): nothing to show.")
        return [view]
    flag_rows = [[f.name.lower(), int(np.count_nonzero(cloud.flags & f.value))] for f in Flag]
    view.table(["flag", "points"], [["(none)", int(np.count_nonzero(cloud.flags == 0))], *flag_rows])
    # Nearest-neighbour spacing, scaled like scanrig.scan.coverage.local_spacing (sqrt(2) d).
    d, _ = cKDTree(cloud.p_world).query(cloud.p_world, k=2)
    spacing_m = np.sqrt(2.0) * d[:, 1]
    truth = _truth_surface(session)
    error_m = truth(cloud.p_world) if truth is not None else None
    fields = []
    if error_m is not None:
        fields.append(("distance to true surface", "mm", error_m * 1e3))
    fields += [("uncertainty (1-sigma, largest axis)", "mm", cloud.sigma * 1e3),
               ("reprojection residual", "px", cloud.residual_px), ("local spacing", "mm", spacing_m * 1e3),
               ("views", "cameras", cloud.n_views), ("frame", "index", cloud.frame)]
    keep = subsample(n, max_points, rng)
    view.text(f"{len(keep)} of {n} points (metres, {frame}); colour scale from the "
              "1st to the 99th percentile.")
    view.raw(viewer_html(cloud.p_world[keep], [(lab, unit, v[keep]) for lab, unit, v in fields]))
    if n >= MIN_DENSITY_POINTS:
        density.image(plots.density_figure(cloud.p_world, spacing_m), "sampling density map")
    else:
        density.note(f"{n} points are too few for a density map (at least {MIN_DENSITY_POINTS}).")
    facts.append(("median local spacing", f"{np.median(spacing_m) * 1e3:.3f} mm"))
    sections = [view, density]
    if error_m is None:
        return sections
    from scanrig.reconstruct.evaluate import OUTLIER_DISTANCE_M, distance_statistics

    stats = distance_statistics(error_m)
    facts.append(("RMS distance of points.ply to the truth", f"{stats['rms_m'] * 1e3:.4f} mm"))
    accuracy.image(plots.histogram_figure(error_m * 1e3, "distance to true surface (mm)",
                                          f"points.ply: {n} points, RMS {stats['rms_m'] * 1e3:.4f} mm",
                                          OUTLIER_DISTANCE_M * 1e3, "outlier threshold"), "error histogram")
    rows = [["points.ply", *_stat_row(stats)]]
    surface_path = session.root / "surface.ply"
    if surface_path.is_file():
        surface = surface_inliers(surface_path)
        if len(surface):
            s_stats = distance_statistics(truth(surface))
            rows.append(["surface.ply (inliers)", *_stat_row(s_stats)])
            facts.append(("RMS distance of surface.ply to the truth", f"{s_stats['rms_m'] * 1e3:.4f} mm"))
    accuracy.table(["cloud", "points", "RMS (mm)", "mean (mm)", "95 % (mm)", "99 % (mm)", "max (mm)",
                    f"beyond {OUTLIER_DISTANCE_M * 1e3:g} mm"], rows)
    return [*sections, accuracy]


def _short(value, limit: int = METADATA_CHARS) -> str:
    text = str(value)
    return text if len(text) <= limit else text[:limit] + f" ... ({len(text)} characters)"


def surface_inliers(path: str | Path) -> np.ndarray:
    """``(N, 3)`` points of a ``surface.ply`` the filter kept (all of them without an ``inlier`` field), metres."""
    from scanrig.io.ply import read_ply

    vertices, _, _ = read_ply(path)
    keep = vertices["inlier"] != 0 if "inlier" in vertices else slice(None)
    return np.column_stack([vertices[k][keep].astype(np.float64) for k in ("x", "y", "z")])


def _stat_row(stats: dict) -> list:
    return [stats["n_points"], *(stats[k] * 1e3 for k in ("rms_m", "mean_m", "p95_m", "p99_m", "max_m")),
            f"{stats['fraction_beyond']:.2%}"]


def _truth_surface(session: Session):
    """Distance function ``(N, 3) -> (N,)`` (metres) to the simulator's true meshes, or None without them."""
    from scanrig.reconstruct.evaluate import load_truth_surface

    if not (session.truth_dir / "meshes").is_dir():
        return None
    return load_truth_surface(session.truth_dir)


# --- run --------------------------------------------------------------------------------------
def _run(session: Session, facts: list) -> list[Section]:
    from scanrig.io.ply import read_ply

    sec = Section("Run: parameters, versions, seed")
    settings = session.settings()
    if settings:
        sec.table(["session.toml", "value"], [[str(k), _short(v)] for k, v in settings.items()])
    rows = []
    for name in ("points.ply", "surface.ply", "mesh.ply"):
        path = session.root / name
        if path.is_file():
            vertices, faces, comments = read_ply(path)
            counts = f"{len(next(iter(vertices.values()))) if vertices else 0} vertices" + (
                f", {len(faces)} faces" if faces is not None else "")
            rows.append([name, counts, " | ".join(comments)])
    if rows:
        sec.table(["file", "contents", "header comments"], rows)
    versions = [["python", platform.python_version()]]
    for package in VERSIONED:
        try:
            versions.append([package, version(package)])
        except PackageNotFoundError:
            versions.append([package, "not installed"])
    sec.table(["package", "version"], versions)
    sec.text(f"Report written {time.strftime('%Y-%m-%d %H:%M:%S %Z')} on {platform.platform()}.")
    return [sec]
