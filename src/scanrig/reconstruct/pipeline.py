"""``reconstruct_session``: rig.toml + traces.parquet -> points.ply, with consistency checks."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError, InputError
from scanrig.geometry.triangulation import MIN_TRIANGULATION_ANGLE_RAD
from scanrig.geometry.uncertainty import sigma_from_covariance
from scanrig.io.object_poses import OBJECT_FRAME_NOTE, object_poses_path, read_object_poses
from scanrig.io.rig_file import load_rig
from scanrig.io.session import Session, read_image
from scanrig.laser.traces import read_traces
from scanrig.reconstruct.candidates import frame_order
from scanrig.reconstruct.correspondence import GATE_PROBABILITY, SIGMA_FLOOR_PX
from scanrig.reconstruct.flags import Flag
from scanrig.reconstruct.light_plane import intersect_stripe_pixels, load_light_plane
from scanrig.reconstruct.points import PointCloud, write_points
from scanrig.reconstruct.spots import reconstruct_spots
from scanrig.reconstruct.stripes import reconstruct_stripes
from scanrig.reconstruct.stripes.precision import split_by_precision
from scanrig.reconstruct.stripes.views import neighbour_segments, stripe_pieces


def check_rig_against_session(rig, session: Session, rig_path: Path) -> None:
    """Check that the scan folders and the rig name the same cameras with the same image sizes.

    Raises
    ------
    FileFormatError
        Naming ``rig_path`` and the first disagreement. Sessions without a ``scan/`` folder
        (traces imported from elsewhere) are not checked.
    """
    if not (session.root / "scan").is_dir():
        return
    folders = session.camera_names("scan")
    missing = [name for name in folders if name not in rig]
    if missing:
        raise FileFormatError(rig_path, f"has no camera {missing} for the scan folders {folders} "
                                        f"(rig cameras: {rig.names})")
    for name in folders:
        paths = session.image_paths("scan", name)
        if not paths:
            continue
        first = next(iter(paths.values()))
        h, w = read_image(first).shape[:2]
        cam = rig[name]
        if (w, h) != (cam.width, cam.height):
            raise FileFormatError(rig_path, f"camera {name!r} is {cam.width}x{cam.height} but "
                                            f"{first.relative_to(session.root)} is {w}x{h}")


def reconstruct_session(
    root: str | Path,
    rig_path: str | Path | None = None,
    out_path: str | Path | None = None,
    sigma_floor_px: float = SIGMA_FLOOR_PX,
    gate_probability: float = GATE_PROBABILITY,
    min_angle_deg: float = float(np.rad2deg(MIN_TRIANGULATION_ANGLE_RAD)),
    keep_ambiguous: bool = False,
    single_view: bool = True,
    light_plane_path: str | Path | None = None,
    seed: int = 0,
    comments=(),
    progress=None,
    max_sigma_m: float | None = None,
    workers: int = 1,
) -> dict:
    """Reconstruct the points of a session and write ``points.ply``.

    Parameters
    ----------
    root : str or Path
        Session folder.
    rig_path : str or Path, optional
        Calibration to use (default ``SESSION/rig.toml``).
    out_path : str or Path, optional
        Output (default ``SESSION/points.ply``).
    sigma_floor_px, gate_probability
        See :func:`~scanrig.reconstruct.correspondence.match_spots`.
    min_angle_deg : float
        Smallest triangulation angle, degrees.
    keep_ambiguous : bool
        Spot mode: also write the best point of ambiguous frames (flagged).
    single_view : bool
        Stripe mode: add the points seen by one camera, intersected with the frame's light plane.
    light_plane_path : str or Path, optional
        Classic single-camera mode: a calibrated ``light_plane.toml``; every brightest stripe
        detection of its camera is intersected with it (no multi-view check, so a single-camera
        rig is accepted). When the session has ``scan/object_poses.csv`` (the object moved
        between frames: turntable, stage), each frame's points are written in the object frame.
    seed : int
        Seed of the robust plane fits (stripe mode); recorded in the header.
    comments : iterable of str
        Extra ``points.ply`` header lines (command line).
    progress : callable, optional
        ``progress(done, total)`` per stripe frame.
    max_sigma_m : float, optional
        Leave out points with a larger predicted sigma, metres (every mode). Default: the 0.1 mm
        accuracy target in multi-view stripe mode (:mod:`scanrig.reconstruct.stripes.precision`),
        no cut in spot and classic single-camera modes.
    workers : int
        Multi-view stripe mode: processes that solve the frames (the points are the same for any
        number).

    Returns
    -------
    dict
        Counts: frames per outcome, points, candidates; ``mode`` and ``out`` path.

    Raises
    ------
    InputError
        Missing or inconsistent inputs: no rig or traces, cameras or image sizes that disagree,
        a single-camera rig, traces that mix spots and stripes.
    """
    session = Session(root)
    rig_path = Path(rig_path) if rig_path is not None else session.rig_path
    if not rig_path.is_file():
        raise FileFormatError(rig_path, "rig file not found (run `scanrig calibrate` first or pass --rig)")
    rig = load_rig(rig_path)
    if light_plane_path is None and len(rig) < 2:
        raise InputError(f"{rig_path}: multi-view reconstruction needs at least 2 cameras, "
                         f"the rig has {len(rig)} ({rig.names})")
    check_rig_against_session(rig, session, rig_path)
    table, metadata = read_traces(session.traces_path)
    if table.num_rows == 0:
        raise FileFormatError(session.traces_path, "holds no traces (did `scanrig detect` find the laser?)")
    kinds = set(table.column("kind").unique().to_pylist())
    if len(kinds) != 1:
        raise FileFormatError(session.traces_path, f"mixes {sorted(kinds)} traces; reconstruct one kind per session")
    mode = kinds.pop()
    frames = frame_order(table, metadata)
    min_angle_rad = float(np.deg2rad(min_angle_deg))
    if light_plane_path is not None:
        if mode != "stripe":
            raise FileFormatError(session.traces_path, "holds spot traces; --light-plane needs stripe traces")
        plane, camera = load_light_plane(light_plane_path)
        if camera not in rig:
            raise FileFormatError(light_plane_path, f"camera {camera!r} is not in {rig_path} (cameras: {rig.names})")
        cloud, summary = _classic_single_camera(rig[camera], plane, table, frames, sigma_floor_px)
        mode = f"stripe, light plane of {camera}"
        poses_path = object_poses_path(session.root)
        if poses_path.is_file():
            cloud = _to_object_frame(cloud, frames, read_object_poses(poses_path), poses_path)
            mode += f", {OBJECT_FRAME_NOTE}"
    elif mode == "spot":
        cloud, summary, _ = reconstruct_spots(rig, table, frames, sigma_floor_px, gate_probability, min_angle_rad,
                                              keep_ambiguous)
    else:
        cloud, summary = reconstruct_stripes(rig, table, frames, np.random.default_rng(seed), sigma_floor_px,
                                             gate_probability, min_angle_rad, single_view, progress,
                                             max_sigma_m=max_sigma_m, workers=workers)
    if max_sigma_m is not None and mode != "stripe":  # multi-view stripe mode made its own cut
        cloud, imprecise = split_by_precision(cloud, max_sigma_m)
        summary.update(points=len(cloud), points_imprecise=len(imprecise),
                       max_sigma_mm=round(1e3 * max_sigma_m, 4))
    out = Path(out_path) if out_path is not None else session.points_path
    stats = " ".join(f"{k}={v}" for k, v in summary.items())
    write_points(out, cloud, comments=(f"rig: {rig_path}", f"seed: {seed}", f"mode: {mode}; {stats}", *comments))
    summary.update(mode=mode, out=str(out), seed=seed)
    return summary


#: In classic mode a line's brightest candidate is kept only on a piece of stripe of at least this
#: many lines: one camera cannot vote, and a line the laser does not cross still has a brightest
#: candidate (noise, texture), which the plane would place in space.
MIN_PIECE_LINES = 5


def _classic_single_camera(camera, plane, table, frames, sigma_floor_px):
    """Stripe points of one camera intersected with its calibrated light plane (the brightest of
    each line, on pieces of stripe of ``MIN_PIECE_LINES`` lines or more)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    rows = table.filter(pc.and_(pc.equal(table.column("camera"), camera.name), pc.equal(table.column("rank"), 0)))
    n_detections = rows.num_rows
    frame = pc.index_in(rows.column("frame"), value_set=pa.array(frames, pa.string())).to_numpy(zero_copy_only=False)
    on_piece = _on_long_pieces(rows, frame)
    rows, frame = rows.filter(pa.array(on_piece)), frame[on_piece]

    def col(name):
        return rows.column(name).to_numpy()

    q = np.c_[col("u"), col("v")]
    cov = np.zeros((len(q), 2, 2))
    cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1] = col("cov_uu"), col("cov_uv"), col("cov_vv")
    cov[:, 1, 0] = cov[:, 0, 1]
    cov += np.eye(2) * sigma_floor_px**2
    p, cov_p = intersect_stripe_pixels(camera, q, cov, plane)
    ok = np.all(np.isfinite(p), axis=1)
    flags = np.full(ok.sum(), Flag.CALIBRATED_PLANE, np.uint16)
    flags[col("saturated")[ok]] |= np.uint16(Flag.SATURATED)
    cloud = PointCloud(p[ok], sigma_from_covariance(cov_p[ok]), np.ones(ok.sum()), np.full(ok.sum(), np.nan),
                       frame[ok], flags)
    return cloud, {"frames": len(frames), "points": len(cloud), "detections": n_detections,
                   "detections_isolated": n_detections - len(q)}


def _on_long_pieces(rows, frame: np.ndarray) -> np.ndarray:
    """Whether each detection lies on a piece of stripe of at least ``MIN_PIECE_LINES`` detections in
    its frame (:func:`~scanrig.reconstruct.stripes.views.stripe_pieces`)."""
    q = np.c_[rows.column("u").to_numpy(), rows.column("v").to_numpy()]
    line = rows.column("line").to_numpy()
    along_rows = q[:, 1] == line
    keep = np.zeros(len(q), bool)
    order = np.argsort(frame, kind="stable")
    bounds = np.flatnonzero(np.diff(frame[order])) + 1
    for index in np.split(order, bounds):  # one frame at a time: a loop over frames, not points
        piece = stripe_pieces(len(index), neighbour_segments(q[index], line[index], along_rows[index]))
        keep[index] = np.bincount(piece)[piece] >= MIN_PIECE_LINES
    return keep


def _to_object_frame(cloud: PointCloud, frames, poses: dict, poses_path: Path) -> PointCloud:
    """Map each frame's points from the world into the moving object's frame (``object_from_world``).

    Parameters
    ----------
    cloud : PointCloud
        Points in the world frame; ``cloud.frame`` indexes ``frames``.
    frames : list of str
        Frame stems in order.
    poses : dict of str to RigidTransform
        ``world_from_object`` per frame stem (:func:`~scanrig.io.object_poses.read_object_poses`).
    poses_path : Path
        The poses file, for the message.

    Returns
    -------
    PointCloud
        The same points in the object frame. ``sigma`` (the covariance's largest axis) is unchanged
        by a rigid motion.

    Raises
    ------
    FileFormatError
        If a frame with points has no pose.
    """
    used = [frames[i] for i in np.unique(cloud.frame)]
    missing = [stem for stem in used if stem not in poses]
    if missing:
        raise FileFormatError(poses_path, f"has no pose for {len(missing)} scan frame(s) with points, e.g. "
                                          f"{missing[:5]}; give world_from_object of every frame")
    # frames without points may lack a pose: the identity stands in, unused
    R = np.stack([poses[f].R if f in poses else np.eye(3) for f in frames])
    t = np.stack([poses[f].t if f in poses else np.zeros(3) for f in frames])
    p_object = np.einsum("nji,nj->ni", R[cloud.frame], cloud.p_world - t[cloud.frame])
    return dataclasses.replace(cloud, p_world=p_object)
