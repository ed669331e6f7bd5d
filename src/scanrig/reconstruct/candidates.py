"""Traces table -> padded per-frame, per-camera candidate arrays for vectorised matching."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from scanrig.errors import InputError
from scanrig.io.session import natural_key

#: Candidates kept per camera and frame, brightest first (``rank``). Spot frames rarely hold more
#: than a spot and two reflections; the hypothesis count grows as (K + 1) ** n_cams.
MAX_CANDIDATES = 4
#: A candidate is a *fixed feature* (a glint of room light on polished metal, a hot pixel), not
#: laser light, when candidates of at least ``STATIC_MIN_FRAMES`` other frames of its camera lie
#: within ``STATIC_RADIUS_PX`` of it and the ring out to ``STATIC_RING_FACTOR`` times that radius
#: holds at most ``STATIC_RING_FRACTION`` times as many: a spike of recurrences at one place. The
#: spot moves with the beam, so it does not come back to the same pixel frame after frame; a
#: scan at a pitch finer than the radius does put other frames' spots inside it, but then the ring
#: holds more (twice as many along a scan line, eight times over a raster), whatever the pitch.
#: The test runs at the radius and at twice it, so that a glint wandering by a few pixels is
#: still one spike. The radius is ~3 sigma of the faint candidates such features make (0.3-1 px);
#: a re-scan of one surface point from several beams would recur too, hence more than a couple
#: of frames. ``STATIC_MIN_FRAMES = 0`` disables the test. Since the detector models each
#: pixel's noise after dark subtraction, glints rarely reach this test (none in the shiny
#: sessions); it stays for scans without a dark frame.
STATIC_RADIUS_PX = 1.5
STATIC_MIN_FRAMES = 3
STATIC_RING_FACTOR = 3.0
STATIC_RING_FRACTION = 0.5
#: Frame index scale that puts candidates of different frames far apart in (u, v, frame) space.
_FRAME_APART_PX = 1e6


@dataclass(frozen=True)
class Candidates:
    """Spot candidates of every frame and camera, padded to ``K``.

    Attributes
    ----------
    frames : list of str
        Frame stems in natural order; the position is the ``frame`` index of ``points.ply``.
    cameras : list of str
        Camera names in rig order.
    q : ndarray of shape (n_frames, n_cams, K, 2)
        Candidate centres, pixels; NaN padding.
    cov : ndarray of shape (n_frames, n_cams, K, 2, 2)
        Centre covariances, px² (NaN padding).
    saturated : ndarray of shape (n_frames, n_cams, K), bool
    count : ndarray of shape (n_frames, n_cams), int
        Candidates kept per frame and camera.
    n_ignored : int
        Candidates beyond ``K`` per camera and frame (the dimmest), not considered.
    static : ndarray of shape (n_frames, n_cams, K), bool, optional
        Fixed features (see ``STATIC_RADIUS_PX``): kept in place, so that indices stay ranks,
        but never matched. None = none.
    """

    frames: list[str]
    cameras: list[str]
    q: np.ndarray
    cov: np.ndarray
    saturated: np.ndarray
    count: np.ndarray
    n_ignored: int
    static: np.ndarray | None = None


def frame_order(table: pa.Table, metadata: dict | None = None) -> list[str]:
    """Frame stems of a traces table in natural order (including frames ``scanrig detect``
    processed without finding a candidate, listed in its metadata under ``frames_done``)."""
    stems = set(table.column("frame").unique().to_pylist())
    for pair in (metadata or {}).get("frames_done", []):
        if isinstance(pair, (list, tuple)) and len(pair) == 2:
            stems.add(str(pair[1]))
    return sorted(stems, key=natural_key)


def spot_candidates(table: pa.Table, cameras: list[str], frames: list[str],
                    max_per_camera: int = MAX_CANDIDATES, static_radius_px: float = STATIC_RADIUS_PX,
                    static_min_frames: int = STATIC_MIN_FRAMES) -> Candidates:
    """Gather the spot rows of a traces table into padded arrays.

    Parameters
    ----------
    table : pyarrow.Table
        Traces (``docs/architecture.md``); only ``kind == "spot"`` rows are used.
    cameras : list of str
        Rig camera names, in rig order; rows of other cameras raise.
    frames : list of str
        Frame stems, in the order that defines frame indices (see :func:`frame_order`).
    max_per_camera : int
        ``K``: candidates kept per camera and frame, by ``rank``.
    static_radius_px, static_min_frames : float, int
        Fixed-feature test (see ``STATIC_RADIUS_PX``); ``static_min_frames = 0`` disables it.

    Raises
    ------
    InputError
        If a row names a camera that is not in ``cameras``.
    """
    spots = table.filter(pc.equal(table.column("kind"), "spot"))
    cam_lookup = pc.index_in(spots.column("camera"), value_set=pa.array(cameras, pa.string()))
    if cam_lookup.null_count:
        bad = sorted(set(pc.filter(spots.column("camera"), pc.is_null(cam_lookup)).to_pylist()))
        raise InputError(f"traces name cameras {bad} that are not in the rig (cameras: {cameras})")
    cam_idx = cam_lookup.to_numpy(zero_copy_only=False).astype(np.int64)
    frame_idx = pc.index_in(spots.column("frame"), value_set=pa.array(frames, pa.string())).to_numpy(
        zero_copy_only=False).astype(np.int64)
    rank = spots.column("rank").to_numpy()
    order = np.lexsort((rank, cam_idx, frame_idx))
    f, c = frame_idx[order], cam_idx[order]
    group = f * len(cameras) + c
    start = np.r_[0, np.flatnonzero(np.diff(group)) + 1]
    pos = np.arange(group.size) - np.repeat(start, np.diff(np.r_[start, group.size]))
    keep = pos < max_per_camera

    n_frames, n_cams, K = len(frames), len(cameras), max_per_camera
    q = np.full((n_frames, n_cams, K, 2), np.nan)
    cov = np.full((n_frames, n_cams, K, 2, 2), np.nan)
    saturated = np.zeros((n_frames, n_cams, K), bool)
    idx = (f[keep], c[keep], pos[keep])
    rows = order[keep]

    def col(name):
        return spots.column(name).to_numpy()[rows]

    q[idx] = np.stack([col("u"), col("v")], axis=1)
    cov[idx + (0, 0)] = col("cov_uu")
    cov[idx + (0, 1)] = cov[idx + (1, 0)] = col("cov_uv")
    cov[idx + (1, 1)] = col("cov_vv")
    saturated[idx] = col("saturated")
    count = np.zeros((n_frames, n_cams), np.int64)
    np.add.at(count, (f[keep], c[keep]), 1)
    static = np.zeros((n_frames, n_cams, K), bool)
    if static_min_frames > 0:
        uv = np.stack([spots.column("u").to_numpy()[order], spots.column("v").to_numpy()[order]], axis=1)
        static[idx] = fixed_features(uv, c, f, static_radius_px, static_min_frames)[keep]
    return Candidates(frames, list(cameras), q, cov, saturated, count, int((~keep).sum()), static)


def fixed_features(uv: np.ndarray, camera: np.ndarray, frame: np.ndarray, radius_px: float,
                   min_frames: int) -> np.ndarray:
    """Which candidates are a spike of recurrences at one pixel of their camera (see ``STATIC_RADIUS_PX``).

    At each scale ``r`` of ``radius_px`` and ``2 · radius_px``: ``n`` candidates of other frames
    within ``r``, ``m`` within ``STATIC_RING_FACTOR · r``; a candidate is fixed when, at either
    scale, ``n ≥ min_frames`` and ``m − n ≤ STATIC_RING_FRACTION · n``. A point-like feature has
    ``m ≈ n``; a uniform scan line ``m ≈ 3 n`` and a raster ``m ≈ 9 n``, at any pitch.

    Parameters
    ----------
    uv : ndarray of shape (N, 2)
        Candidate centres, pixels.
    camera, frame : ndarray of shape (N,), int
        Camera and frame index of each candidate.
    radius_px : float
        The smaller scale, pixels.
    min_frames : int
        Candidates of other frames needed within the radius (a frame's own candidates are at
        least the detector's separation, 3 px, apart: within the radius a frame counts once).

    Returns
    -------
    ndarray of shape (N,), bool
    """
    from scipy.spatial import cKDTree

    out = np.zeros(len(uv), bool)
    if min_frames <= 0:
        return out
    for cam in np.unique(camera):
        rows = np.flatnonzero(camera == cam)
        points = uv[rows].astype(float)
        # the same frame's candidates (itself included) are no recurrence: counted in (u, v, frame)
        spaced = np.c_[points, frame[rows] * _FRAME_APART_PX]
        tree, own = cKDTree(points), cKDTree(spaced)

        def others(r, idx):
            return (tree.query_ball_point(points[idx], r, return_length=True)
                    - own.query_ball_point(spaced[idx], r, return_length=True))

        everyone = np.arange(rows.size)
        for scale in (radius_px, 2.0 * radius_px):
            near = others(scale, everyone)
            idx = np.flatnonzero(near >= min_frames)
            if idx.size == 0:
                continue
            ring = others(STATIC_RING_FACTOR * scale, idx) - near[idx]
            out[rows[idx[ring <= STATIC_RING_FRACTION * near[idx]]]] = True
    return out
