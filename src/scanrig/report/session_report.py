"""``write_report``: one self-contained ``report.html`` from whatever a session folder holds.

Each section uses the files that exist and says plainly which are missing:

==========================  ======================================================================
section                     reads
==========================  ======================================================================
verdict (first screen)      what was scanned, points, accuracy against the truth before and after
                            the filter, coverage, beside the 3-D view of ``mesh.ply`` and
                            ``points.ply`` coloured by distance to the truth (:mod:`.cloud_sections`)
summary                     everything below, plus the caller's summary rows (e.g. the demo's)
calibration                 ``rig.toml``, ``calibration_report/`` (summary, residual, coverage and
                            projection-uncertainty plots written by ``scanrig calibrate``)
light plane                 ``light_plane.toml``, its summary and residual plots in ``calibration_report/``,
                            ``scan/object_poses.csv`` (only sessions that have one of them)
detection                   ``traces.parquet`` and ``scan/<camera>/<frame>`` images (overlays)
point cloud                 ``points.ply``: flags
sampling density            ``points.ply``
accuracy against truth      ``points.ply``, ``surface.ply``, ``rig.toml`` and ``truth/`` (the
                            figures of ``scanrig evaluate SESSION``)
inspection against CAD      ``inspection/inspection.json`` (and a link to ``inspection.html``), when present
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
from scanrig.io.session import Session
from scanrig.report import plots
from scanrig.report.cloud_sections import (
    cloud_sections,
    first_screen,
    inspection_section,
    load_cloud,
)
from scanrig.report.html import Section, page
from scanrig.report.light_plane_section import light_plane_sections
from scanrig.report.viewer import MAX_VIEWER_POINTS

#: Packages whose versions the report records.
VERSIONED = ("scanrig", "numpy", "scipy", "opencv-python-headless", "trimesh", "torch", "matplotlib", "pyarrow")
#: Side of the square crop around a detection in the overlays, pixels of the frame (shown enlarged).
OVERLAY_CROP_PX = 160
#: Longest metadata value shown in full.
METADATA_CHARS = 300
#: Frames shown as detection overlays.
OVERLAY_FRAMES = 2

Progress = Callable[[str], None]


def write_report(session_root: str | Path, out: str | Path | None = None, *, rng: np.random.Generator,
                 summary: list[tuple[str, str]] | None = None, subject: str | None = None,
                 max_points: int = MAX_VIEWER_POINTS, progress: Progress | None = None) -> Path:
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
    subject : str, optional
        What was scanned, for the verdict (default: the session's frames, cameras and true objects).
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
                        ("detection", _detection)):
        progress(name)
        sections += build(session, facts)
    progress("point cloud")
    data = load_cloud(session)
    verdict = first_screen(session, data, facts, subject or _subject(session), rng, max_points)
    sections += cloud_sections(data, facts) + inspection_section(session, facts)
    progress("run")
    sections += _run(session, facts)
    summary_section = Section("Summary")
    summary_section.table(["quantity", "value"], [[k, v] for k, v in [*(summary or []), *facts]])
    html = page(f"scanrig report: {session.root.resolve().name}", [verdict, summary_section, *sections])
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
            sec.text("Detections outlined on the frames (crops, enlarged): ticks either side of a stripe, a circle "
                     "around a spot; rank-0 candidates green, others orange.")
            sec.gallery(gallery)
    return [sec]


def _overlays(session: Session, table, cams, frames, rank) -> list[tuple[str, str]]:
    import pyarrow.compute as pc

    from scanrig.io.session import read_image
    from scanrig.report.markers import outlined_crop

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
            image = read_image(path)
            best = mask & (rank == 0)
            u = np.median(table.column("u").to_numpy()[best if best.any() else mask])
            v = np.median(table.column("v").to_numpy()[best if best.any() else mask])
            h, w = image.shape[:2]
            half = OVERLAY_CROP_PX // 2
            u0 = int(np.clip(round(u) - half, 0, max(w - OVERLAY_CROP_PX, 0)))
            v0 = int(np.clip(round(v) - half, 0, max(h - OVERLAY_CROP_PX, 0)))
            crop = outlined_crop(image, rows, u0, v0, OVERLAY_CROP_PX)
            items.append((plots.image_uri(crop), (f"frame {frame}, {cam} (crop at u={u0}, v={v0}, enlarged; "
                                                  f"{int(mask.sum())} candidates)")))
    return items


def _subject(session: Session) -> str:
    """What a session scanned, from its files: the simulator's true objects, frames and cameras."""
    cameras = session.camera_names("scan") if (session.root / "scan").is_dir() else []
    meshes = sorted((session.truth_dir / "meshes").glob("*.ply")) if (session.truth_dir / "meshes").is_dir() else []
    parts = [f"the simulator's {', '.join(p.stem for p in meshes)}"] if meshes else []
    if cameras:
        frames = len(session.image_paths("scan", cameras[0]))
        parts.append(f"{frames} {session.settings().get('laser_mode', 'laser')} frames of {len(cameras)} cameras")
    return ", ".join(parts) or "this session (no scan images, no truth)"


def _short(value, limit: int = METADATA_CHARS) -> str:
    text = str(value)
    return text if len(text) <= limit else text[:limit] + f" ... ({len(text)} characters)"


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
