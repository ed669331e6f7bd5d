"""Report section of the classic single-camera mode: the light plane(s) and the object's motion.

Reads ``light_plane.toml`` (or ``light_plane_<camera>.toml``), the light-plane summary and residual
plots that ``scanrig calibrate --light-plane`` writes to ``calibration_report/``, and
``scan/object_poses.csv``. A session with none of them (a multi-camera session) gets no section.
"""

from __future__ import annotations

import numpy as np

from scanrig.errors import FileFormatError
from scanrig.io.object_poses import OBJECT_POSES_FILE, object_poses_path, read_object_poses
from scanrig.io.session import Session, natural_key
from scanrig.report import plots
from scanrig.report.html import Section

#: Light-plane files of a session: ``light_plane.toml``, or one ``light_plane_<camera>.toml`` per camera.
PLANE_GLOB = "light_plane*.toml"


def light_plane_sections(session: Session, facts: list) -> list[Section]:
    """The light-plane section (empty list when the session has no plane and no object poses).

    Parameters
    ----------
    session : Session
    facts : list of (str, str)
        Summary rows; one per plane is appended.
    """
    planes = sorted(session.root.glob(PLANE_GLOB), key=lambda p: natural_key(p.name))
    poses_path = object_poses_path(session.root)
    if not planes and not poses_path.is_file():
        return []
    sec = Section("Light plane and object motion")
    _planes(sec, session, planes, facts)
    if poses_path.is_file():
        _motion(sec, poses_path)
    return [sec]


def _planes(sec: Section, session: Session, paths: list, facts: list) -> None:
    from scanrig.calibration.pipeline import REPORT_DIR
    from scanrig.reconstruct.light_plane import load_light_plane

    if not paths:
        sec.note("light_plane.toml not found: the laser's plane is not calibrated (scanrig calibrate --light-plane).")
        return
    rows = []
    for path in paths:
        try:
            plane, camera = load_light_plane(path)
        except FileFormatError as exc:
            sec.note(str(exc))
            continue
        n = ", ".join(f"{v:+.6f}" for v in plane.normal)
        at_centroid_mm = 1e3 * float(plane.offset_sigma(plane.centroid[None])[0])
        inliers = f"{float(plane.n_inliers):g}"
        rows.append([path.name, camera, f"[{n}]", 1e3 * plane.offset, 1e3 * plane.residual_m, inliers, at_centroid_mm])
        facts.append((f"light plane of {camera}", f"RMS {1e3 * plane.residual_m:.4f} mm, {inliers} inliers"))
    if rows:
        sec.text("The laser's plane, normal · x = offset (world frame of rig.toml); the RMS is the distance of "
                 "the inlier stripe points on the target to the plane (inliers: an effective number when the fit "
                 "allowed for correlated errors); sigma is the plane's position uncertainty at the inliers' "
                 "centroid.")
        sec.table(["file", "camera", "normal", "offset (mm)", "RMS (mm)", "inliers", "sigma (mm)"], rows)
    folder = session.root / REPORT_DIR
    summary = folder / "light_plane_summary.txt"
    if summary.is_file():
        sec.pre(summary.read_text(encoding="utf-8"))
    pngs = sorted(folder.glob("light_plane_*.png"), key=lambda p: natural_key(p.name))
    if not pngs:
        sec.note(f"{REPORT_DIR}/light_plane_<camera>.png not found: no residual plot "
                 "(scanrig calibrate --light-plane writes it).")
    for path in pngs:
        sec.image(plots.data_uri(path.read_bytes()), f"light-plane residuals: {path.name}")


def _motion(sec: Section, path) -> None:
    try:
        poses = read_object_poses(path)
    except FileFormatError as exc:
        sec.note(str(exc))
        return
    R = np.stack([p.R for p in poses.values()])
    t = np.stack([p.t for p in poses.values()])
    rows = [["frames", len(poses)]]
    if len(poses) > 1:
        step_deg = np.degrees(_rotation_angle(R[1:] @ R[:-1].transpose(0, 2, 1)))
        move_mm = 1e3 * np.linalg.norm(np.diff(t, axis=0), axis=1)
        rows += [["rotation between frames (deg): median, min, max",
                  f"{np.median(step_deg):.4f}, {step_deg.min():.4f}, {step_deg.max():.4f}"],
                 ["rotation in all (deg, sum of the steps)", f"{step_deg.sum():.3f}"],
                 ["move of the object origin between frames (mm): median, max",
                  f"{np.median(move_mm):.4f}, {move_mm.max():.4f}"]]
    sec.text(f"{OBJECT_POSES_FILE.as_posix()}: where the object was at each frame (world_from_object); "
             "points.ply is in the object frame.")
    sec.table(["object motion", "value"], rows)


def _rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angles ``(N,)`` of rotations ``(N, 3, 3)``, radians (from the trace, clipped against round-off)."""
    return np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
