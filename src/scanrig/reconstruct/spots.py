"""Spot mode: one laser spot per frame, matched across cameras and triangulated."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from scanrig.geometry.triangulation import MIN_TRIANGULATION_ANGLE_RAD
from scanrig.reconstruct.candidates import MAX_CANDIDATES, spot_candidates
from scanrig.reconstruct.correspondence import (
    GATE_PROBABILITY,
    SIGMA_FLOOR_PX,
    FrameStatus,
    SpotMatches,
    match_spots,
)
from scanrig.reconstruct.points import PointCloud


def reconstruct_spots(
    rig,
    table: pa.Table,
    frames: list[str],
    sigma_floor_px: float = SIGMA_FLOOR_PX,
    gate_probability: float = GATE_PROBABILITY,
    min_angle_rad: float = MIN_TRIANGULATION_ANGLE_RAD,
    keep_ambiguous: bool = False,
    max_candidates: int = MAX_CANDIDATES,
):
    """Points of every spot frame of a traces table.

    Parameters
    ----------
    rig : Rig
        Calibrated cameras; traces must name only these.
    table : pyarrow.Table
        Traces (spot rows are used).
    frames : list of str
        Frame stems in natural order (defines the ``frame`` index).
    sigma_floor_px, gate_probability, min_angle_rad
        See :func:`~scanrig.reconstruct.correspondence.match_spots`.
    keep_ambiguous : bool
        Also output the best point of ambiguous frames (flagged AMBIGUOUS).
    max_candidates : int
        Candidates considered per camera and frame, brightest first.

    Returns
    -------
    cloud : PointCloud
        One point per matched frame.
    summary : dict
        Frame counts per outcome and candidate counts (``n_candidates``, ``n_candidates_used``,
        ``n_candidates_ignored`` beyond ``max_candidates``, ``n_candidates_static``: fixed
        features, see :data:`~scanrig.reconstruct.candidates.STATIC_RADIUS_PX`).
    matches : SpotMatches
        Per-frame details (choices, statuses).
    """
    cand = spot_candidates(table, rig.names, frames, max_candidates)
    matches: SpotMatches = match_spots(rig, cand, sigma_floor_px, gate_probability, min_angle_rad)
    keep = matches.status == FrameStatus.MATCHED
    if keep_ambiguous:
        keep |= matches.status == FrameStatus.AMBIGUOUS
    keep &= matches.info.ok
    info = matches.info
    cloud = PointCloud(matches.p_world[keep], info.sigma[keep], info.n_views[keep], info.residual_px[keep],
                       np.flatnonzero(keep), matches.flags[keep])
    counts = np.bincount(matches.status, minlength=len(FrameStatus))
    summary = {f"frames_{s.name.lower()}": int(counts[s]) for s in FrameStatus}
    summary.update(
        frames=len(frames),
        points=len(cloud),
        n_candidates=int(cand.count.sum()) + cand.n_ignored,
        n_candidates_used=int((matches.choice >= 0).sum()),
        n_candidates_ignored=cand.n_ignored,
        n_candidates_static=int(cand.static.sum()) if cand.static is not None else 0,
    )
    return cloud, summary, matches
