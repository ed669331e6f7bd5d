"""``reconstruct_stripes``: the points of every stripe frame of a session's traces."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from scanrig.errors import InputError
from scanrig.geometry.triangulation import MIN_TRIANGULATION_ANGLE_RAD
from scanrig.parallel import run_indexed
from scanrig.reconstruct.correspondence import GATE_PROBABILITY, SIGMA_FLOOR_PX
from scanrig.reconstruct.points import PointCloud
from scanrig.reconstruct.stripes.epipolar import frame_branches
from scanrig.reconstruct.stripes.floor import estimate_calibration_floor, floor_samples, inflate_views
from scanrig.reconstruct.stripes.frame import reconstruct_stripe_frame
from scanrig.reconstruct.stripes.precision import TARGET_SIGMA_M
from scanrig.reconstruct.stripes.views import frame_views


def reconstruct_stripes(
    rig,
    table: pa.Table,
    frames: list[str],
    rng: np.random.Generator,
    sigma_floor_px: float = SIGMA_FLOOR_PX,
    gate_probability: float = GATE_PROBABILITY,
    min_angle_rad: float = MIN_TRIANGULATION_ANGLE_RAD,
    single_view: bool = True,
    progress=None,
    estimate_floor: bool = True,
    max_sigma_m: float | None = None,
    workers: int = 1,
):
    """Points of every stripe frame of a traces table.

    Parameters
    ----------
    rig : Rig
        At least two calibrated cameras.
    table : pyarrow.Table
        Traces; ``kind == "stripe"`` rows are used.
    frames : list of str
        Frame stems in natural order (defines the ``frame`` index).
    rng : numpy.random.Generator
        Draws one seed per frame, the generator of that frame's robust plane fit: the points do not
        depend on ``workers``.
    sigma_floor_px, gate_probability, min_angle_rad
        As in spot mode.
    single_view : bool
        Add the points seen by one camera only, intersected with the frame's plane.
    progress : callable, optional
        ``progress(done, total)`` after each frame.
    estimate_floor : bool
        Raise the calibration floor per camera and image radius where the three-view points show
        the calibration to be worse than ``sigma_floor_px`` (:func:`estimate_calibration_floor`).
    max_sigma_m : float, optional
        Points whose error across their stripe may exceed this (metres) are left out; default the
        0.1 mm accuracy target (:mod:`scanrig.reconstruct.stripes.precision` says why;
        ``numpy.inf`` keeps every point that passed its tests).
    workers : int
        Processes that solve the frames (forked; one runs them in this process).

    Returns
    -------
    cloud : PointCloud
    summary : dict
        Frames, frames with a plane, multi-view and single-view points, two-view pairs (branches
        of epipolar crossings) and those rejected (off the plane, no plane to test them, located
        by the plane only, where the plane is not known, contradicted by a third camera), points
        left out as imprecise and the
        sigma limit (``max_sigma_mm``), and the largest estimated extra calibration noise
        (``floor_extra_px``).
    """
    if len(rig) < 2:
        raise InputError(f"multi-view reconstruction needs at least 2 cameras, the rig has {len(rig)}")
    if not (isinstance(workers, int) and workers >= 1):
        raise InputError(f"workers must be an integer of at least 1, got {workers!r}")
    stripes = table.filter(pc.equal(table.column("kind"), "stripe"))
    unknown = sorted(set(stripes.column("camera").unique().to_pylist()) - set(rig.names))
    if unknown:
        raise InputError(f"traces name cameras {unknown} that are not in the rig (cameras: {rig.names})")
    floor = np.eye(2) * sigma_floor_px**2
    frame_idx = pc.index_in(stripes.column("frame"), value_set=pa.array(frames, pa.string())).to_numpy(
        zero_copy_only=False)
    order = np.argsort(frame_idx, kind="stable")
    bounds = np.searchsorted(frame_idx[order], np.arange(len(frames) + 1))
    views_of, branches_of = {}, {}
    for f in range(len(frames)):
        rows = order[bounds[f]:bounds[f + 1]]
        if rows.size:
            views_of[f] = frame_views(rig, stripes.take(pa.array(rows)), floor)
            branches_of[f] = frame_branches(rig, views_of[f])  # geometry only: kept across the floor
    extra_px = 0.0
    if estimate_floor:
        samples = [x for f, views in views_of.items() for x in floor_samples(rig, views, branches_of[f])]
        edges, s2 = estimate_calibration_floor(samples, len(rig), gate_probability)
        extra_px = float(np.sqrt(s2.max()))
        if s2.any():
            for views in views_of.values():
                inflate_views(rig, views, edges, s2)
    limit_m = TARGET_SIGMA_M if max_sigma_m is None else max_sigma_m
    frame_seeds = rng.integers(2**63, size=len(frames))

    def solve_frame(f: int):
        if f not in views_of:
            return None
        return reconstruct_stripe_frame(rig, views_of[f], f, np.random.default_rng(frame_seeds[f]), gate_probability,
                                        min_angle_rad, single_view, branches_of[f], limit_m)

    solved = [x for x in run_indexed(solve_frame, len(frames), workers,
                                     None if progress is None else lambda done: progress(done, len(frames)))
              if x is not None]
    totals = dict(multi_view=0, single_view=0, imprecise=0, off_plane_pairs=0, pairs=0, plane=0)
    for _, counts in solved:
        for k, v in counts.items():
            totals[k] += v
    clouds = [cloud for cloud, _ in solved]
    cloud = PointCloud.concatenate(clouds)
    summary = dict(frames=len(frames), points=len(cloud), frames_with_plane=totals["plane"],
                   points_multi_view=totals["multi_view"], points_single_view=totals["single_view"],
                   points_imprecise=totals["imprecise"], max_sigma_mm=round(1e3 * limit_m, 4),
                   pairs=totals["pairs"], pairs_off_plane=totals["off_plane_pairs"],
                   floor_extra_px=round(extra_px, 3))
    return cloud, summary
