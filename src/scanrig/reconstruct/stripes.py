"""Stripe mode: stripe points matched along epipolar lines, the frame's light plane, single views.

For every frame:

1. Each stripe point ``a`` of a camera ``i`` is matched in every other camera ``j`` where ``a``'s
   epipolar line crosses ``j``'s stripe: ``j``'s detections are joined into segments between
   neighbours (closer than :data:`NEIGHBOUR_PX`), and the crossing is interpolated on the
   segment whose ends lie on either side of the line (in undistorted normalised coordinates,
   where epipolar lines are straight). Reflections give extra crossings.
2. All ``(a, crossing)`` pairs are triangulated, and the light plane of the frame is fitted to
   them robustly (RANSAC then weighted least squares): the true stripe is planar, pairs that
   involve a reflection are not.
3. For each ``a`` the on-plane crossings (the nearest one per camera) are triangulated together
   with ``a`` (Gauss–Newton, χ² gate); these are the multi-view points.
4. Brightest-on-their-line points of a camera that have no crossing in any other camera (seen by
   that camera only) are intersected with the plane (flag ``PLANE_SINGLE_VIEW``), unless the ray
   meets the plane so obliquely that the point would be much less precise than the multi-view
   ones. Points whose crossings are all off the plane are dropped as reflections.

The plane is fitted to the points on which three cameras agree (a reflection seen by one camera
cannot be among them) when there are enough, else to all pairs. A stripe that is nearly a straight
line in space leaves the plane's tilt about that line poorly determined; the plane's own
uncertainty then widens the gate and the single-view sigma.

Every camera serves as reference in turn, so a surface point seen by three cameras is sampled by
each camera's own scan lines.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from scipy.spatial import cKDTree
from scipy.stats import chi2 as chi2_dist

from scanrig.errors import InputError
from scanrig.geometry.triangulation import MIN_TRIANGULATION_ANGLE_RAD, triangulate
from scanrig.geometry.uncertainty import sigma_from_covariance
from scanrig.reconstruct.correspondence import GATE_PROBABILITY, SIGMA_FLOOR_PX
from scanrig.reconstruct.flags import Flag
from scanrig.reconstruct.light_plane import (
    INLIER_SIGMAS,
    MIN_PLANE_POINTS,
    fit_plane_robust,
    intersect_plane,
    ray_plane_covariance,
)
from scanrig.reconstruct.points import PointCloud

#: Two detections of one camera closer than this (pixels) are neighbours on a stripe: samples
#: are one pixel apart along the scan direction, sqrt(2) on a 45° stripe, and up to ~2.7 px for a
#: stripe at 70° to its scan lines (a detector that scans rows only).
NEIGHBOUR_PX = 3.0
#: A single-view point is kept only if its sigma is at most this multiple of the median sigma of
#: the frame's multi-view points: rays that meet the light plane at a grazing angle add nothing.
SINGLE_VIEW_SIGMA_RATIO = 3.0


class _View:
    """One camera's stripe detections in one frame, with rays and normalised coordinates."""

    def __init__(self, cam, q, cov, rank, saturated):
        self.q, self.cov, self.rank, self.saturated = q, cov, rank, saturated
        xy, _ = cam.unproject(q) if len(q) else (np.zeros((0, 2)), None)
        R = cam.cam_from_world.R
        d_cam = np.c_[xy, np.ones(len(xy))]
        d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
        self.xh = np.c_[xy, np.ones(len(xy))]  # homogeneous normalised coordinates
        self.dirs = d_cam @ R  # world directions (R.T applied to row vectors)
        pairs = cKDTree(q).query_pairs(NEIGHBOUR_PX, output_type="ndarray") if len(q) > 1 else np.zeros((0, 2), int)
        ok = np.all(np.isfinite(xy[pairs[:, 0]]), axis=1) & np.all(np.isfinite(xy[pairs[:, 1]]), axis=1)
        self.segments = pairs[ok]


def _essential(cam_i, cam_j) -> np.ndarray:
    """``E`` with ``x_jᵀ E x_i = 0`` for normalised coordinates of cameras i and j."""
    j_from_i = cam_j.cam_from_world @ cam_i.cam_from_world.inverse()
    t = j_from_i.t
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return tx @ j_from_i.R


def _crossings(cam_i, view_i: _View, cam_j, view_j: _View):
    """Where each point of view i's epipolar line crosses view j's stripe segments.

    Returns
    -------
    a : ndarray of shape (M,), int
        Index of the point in view i.
    q, cov, dirs, saturated : arrays of M rows
        Interpolated pixel, covariance, world direction and saturation of the crossing in view j.
    """
    if len(view_i.q) == 0 or len(view_j.segments) == 0:
        empty = np.zeros((0,), int)
        return empty, np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros((0, 3)), np.zeros(0, bool)
    lines = view_i.xh @ _essential(cam_i, cam_j).T  # (n_i, 3): line in j's normalised plane
    S = view_j.xh @ lines.T  # (n_j, n_i) signed (unnormalised) distances
    b1, b2 = view_j.segments[:, 0], view_j.segments[:, 1]
    s1, s2 = S[b1], S[b2]
    seg, a = np.nonzero((s1 * s2 <= 0.0) & (s1 != s2))
    t = (s1[seg, a] / (s1[seg, a] - s2[seg, a]))
    i1, i2 = b1[seg], b2[seg]

    def lerp(x):
        tt = t.reshape((-1,) + (1,) * (x.ndim - 1))
        return x[i1] + tt * (x[i2] - x[i1])

    dirs = lerp(view_j.dirs)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return a, lerp(view_j.q), lerp(view_j.cov), dirs, view_j.saturated[i1] | view_j.saturated[i2]


def _frame_views(rig, table_frame: pa.Table, floor_cov):
    views = []
    for cam in rig.cameras:
        rows = table_frame.filter(pc.equal(table_frame.column("camera"), cam.name))

        def col(name, rows=rows):
            return rows.column(name).to_numpy()

        q = np.c_[col("u"), col("v")] if rows.num_rows else np.zeros((0, 2))
        cov = np.zeros((len(q), 2, 2))
        if len(q):
            cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1] = col("cov_uu"), col("cov_uv"), col("cov_vv")
            cov[:, 1, 0] = cov[:, 0, 1]
        views.append(_View(cam, q, cov + floor_cov, col("rank") if len(q) else np.zeros(0, int),
                           col("saturated") if len(q) else np.zeros(0, bool)))
    return views


def _three_view_points(rig, q_obs, cov_obs, dirs_obs, ref_cam, other_cam, ref_idx, gate_probability,
                       min_angle_rad):
    """Points where a reference detection's crossings in two other cameras agree (χ² gate).

    A reflection seen by one camera cannot pass this test, so these points fit the light plane
    even when the stripe is nearly straight and a reflection's pairs would fit a tilted plane as
    well as the true ones.
    """
    n_cams = q_obs.shape[0]
    rows_a, rows_b = [], []
    for i in range(n_cams):
        for j in range(n_cams):
            for k in range(j + 1, n_cams):
                if i in (j, k):
                    continue
                rj = np.flatnonzero((ref_cam == i) & (other_cam == j))
                rk = np.flatnonzero((ref_cam == i) & (other_cam == k))
                # every (rj, rk) with the same reference point
                match = ref_idx[rj][:, None] == ref_idx[rk][None, :]
                aj, ak = np.nonzero(match)
                rows_a.append(rj[aj])
                rows_b.append(rk[ak])
    ra, rb = np.concatenate(rows_a), np.concatenate(rows_b)
    if ra.size == 0:
        return np.zeros((0, 3)), np.zeros(0)
    other_b = other_cam[rb]
    q3 = q_obs[:, ra].copy()
    cov3 = cov_obs[:, ra].copy()
    dirs3 = dirs_obs[:, ra].copy()
    cols = np.arange(ra.size)
    q3[other_b, cols], cov3[other_b, cols], dirs3[other_b, cols] = q_obs[other_b, rb], cov_obs[other_b, rb], \
        dirs_obs[other_b, rb]
    p3, info3 = triangulate(rig, q3, cov_px=cov3, refine=False, min_angle_rad=min_angle_rad, dirs=dirs3)
    good = info3.ok & (info3.chi2 <= chi2_dist.ppf(gate_probability, 3))
    return p3[good], info3.sigma[good]


def reconstruct_stripe_frame(rig, views, frame_index: int, rng, gate_probability: float,
                             min_angle_rad: float, single_view: bool):
    """Points of one stripe frame (see the module notes); returns a PointCloud and counts."""
    cams = rig.cameras
    n_cams = len(cams)
    counts = dict(multi_view=0, single_view=0, off_plane_pairs=0, pairs=0, plane=0)
    # 1. all (reference point, crossing) pairs
    pairs = []
    for i in range(n_cams):
        for j in range(n_cams):
            if i != j:
                a, q, cov, dirs, sat = _crossings(cams[i], views[i], cams[j], views[j])
                pairs.append((i, j, a, q, cov, dirs, sat))
    n_pairs = sum(len(p[2]) for p in pairs)
    counts["pairs"] = n_pairs
    if n_pairs == 0:
        return PointCloud.empty(), counts
    # 2. triangulate every pair (closed form) and fit the plane
    q_obs = np.full((n_cams, n_pairs, 2), np.nan)
    cov_obs = np.full((n_cams, n_pairs, 2, 2), np.nan)
    dirs_obs = np.full((n_cams, n_pairs, 3), np.nan)
    ref_cam = np.empty(n_pairs, int)
    other_cam = np.empty(n_pairs, int)
    ref_idx = np.empty(n_pairs, int)
    start = 0
    for i, j, a, q, cov, dirs, _ in pairs:
        s = slice(start, start + len(a))
        q_obs[i, s], cov_obs[i, s], dirs_obs[i, s] = views[i].q[a], views[i].cov[a], views[i].dirs[a]
        q_obs[j, s], cov_obs[j, s], dirs_obs[j, s] = q, cov, dirs
        ref_cam[s], other_cam[s], ref_idx[s] = i, j, a
        start += len(a)
    p2, info2 = triangulate(rig, q_obs, cov_px=cov_obs, refine=False, min_angle_rad=min_angle_rad, dirs=dirs_obs)
    ok2 = info2.ok
    p3, sigma3 = _three_view_points(rig, q_obs, cov_obs, dirs_obs, ref_cam, other_cam, ref_idx,
                                    gate_probability, min_angle_rad)
    if len(p3) >= MIN_PLANE_POINTS:
        plane, _ = fit_plane_robust(p3, sigma3, rng)
    else:  # two cameras (or little overlap): only pairs are available
        plane, _ = fit_plane_robust(p2[ok2], info2.sigma[ok2], rng)
    if plane is None:
        return PointCloud.empty(), counts
    counts["plane"] = 1
    on_plane = np.zeros(n_pairs, bool)
    gate = INLIER_SIGMAS * np.sqrt(info2.sigma[ok2] ** 2 + plane.offset_sigma(p2[ok2]) ** 2)
    dist = np.full(n_pairs, np.inf)
    dist[ok2] = np.abs(plane.distance(p2[ok2]))
    on_plane[ok2] = dist[ok2] <= gate
    counts["off_plane_pairs"] = int((ok2 & ~on_plane).sum())

    sigma_ref = np.median(info2.sigma[on_plane]) if on_plane.any() else 0.0
    clouds = []
    for i in range(n_cams):
        n_i = len(views[i].q)
        if n_i == 0:
            continue
        # 3. per reference point: nearest on-plane crossing in each other camera
        q_m = np.full((n_cams, n_i, 2), np.nan)
        cov_m = np.full((n_cams, n_i, 2, 2), np.nan)
        dirs_m = np.full((n_cams, n_i, 3), np.nan)
        sat = views[i].saturated.copy()
        q_m[i], cov_m[i], dirs_m[i] = views[i].q, views[i].cov, views[i].dirs
        for j in range(n_cams):
            sel = np.flatnonzero((ref_cam == i) & (other_cam == j) & on_plane)
            if sel.size == 0:
                continue
            order = sel[np.lexsort((dist[sel], ref_idx[sel]))]
            first = np.r_[True, ref_idx[order][1:] != ref_idx[order][:-1]]
            best = order[first]
            a = ref_idx[best]
            q_m[j, a], cov_m[j, a], dirs_m[j, a] = q_obs[j, best], cov_obs[j, best], dirs_obs[j, best]
        p, info = triangulate(rig, q_m, cov_px=cov_m, refine=True, min_angle_rad=min_angle_rad, dirs=dirs_m)
        dof = np.maximum(2 * info.n_views.astype(int) - 3, 1)
        good = info.ok & (info.chi2 <= chi2_dist.ppf(gate_probability, dof))
        flags = np.zeros(n_i, np.uint16)
        flags[views[i].rank > 0] |= np.uint16(Flag.REJECTED_CANDIDATES)
        flags[sat] |= np.uint16(Flag.SATURATED)
        clouds.append(PointCloud(p[good], info.sigma[good], info.n_views[good], info.residual_px[good],
                                 np.full(good.sum(), frame_index), flags[good]))
        counts["multi_view"] += int(good.sum())
        # 4. single view: brightest on its line, no crossing at all in any other camera
        if single_view:
            crossed = np.zeros(n_i, bool)
            crossed[ref_idx[ref_cam == i]] = True
            lone = ~crossed & (views[i].rank == 0) & np.all(np.isfinite(views[i].dirs), axis=1)
            centers = np.repeat(cams[i].center_world[None], lone.sum(), axis=0)
            p1, t1 = intersect_plane(centers, views[i].dirs[lone], plane)
            fin = np.all(np.isfinite(p1), axis=1)
            focal = np.sqrt(cams[i].params[0] * cams[i].params[1])
            sig_px = np.sqrt(0.5 * np.trace(views[i].cov[lone], axis1=1, axis2=2))
            cov1 = ray_plane_covariance(views[i].dirs[lone][fin], t1[fin], sig_px[fin] / focal, plane, p1[fin])
            sigma1 = sigma_from_covariance(cov1)
            sharp = sigma1 <= SINGLE_VIEW_SIGMA_RATIO * sigma_ref
            flags1 = flags[lone][fin][sharp] | np.uint16(Flag.PLANE_SINGLE_VIEW)
            clouds.append(PointCloud(p1[fin][sharp], sigma1[sharp], np.ones(sharp.sum()),
                                     np.full(sharp.sum(), np.nan), np.full(sharp.sum(), frame_index), flags1))
            counts["single_view"] += int(sharp.sum())
    return PointCloud.concatenate(clouds), counts


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
        For the robust plane fits.
    sigma_floor_px, gate_probability, min_angle_rad
        As in spot mode.
    single_view : bool
        Add the points seen by one camera only, intersected with the frame's plane.
    progress : callable, optional
        ``progress(done, total)`` after each frame.

    Returns
    -------
    cloud : PointCloud
    summary : dict
        Frames, frames with a plane, multi-view and single-view points, pairs rejected off-plane.
    """
    if len(rig) < 2:
        raise InputError(f"multi-view reconstruction needs at least 2 cameras, the rig has {len(rig)}")
    stripes = table.filter(pc.equal(table.column("kind"), "stripe"))
    unknown = sorted(set(stripes.column("camera").unique().to_pylist()) - set(rig.names))
    if unknown:
        raise InputError(f"traces name cameras {unknown} that are not in the rig (cameras: {rig.names})")
    floor = np.eye(2) * sigma_floor_px**2
    frame_idx = pc.index_in(stripes.column("frame"), value_set=pa.array(frames, pa.string())).to_numpy(
        zero_copy_only=False)
    order = np.argsort(frame_idx, kind="stable")
    bounds = np.searchsorted(frame_idx[order], np.arange(len(frames) + 1))
    totals = dict(multi_view=0, single_view=0, off_plane_pairs=0, pairs=0, plane=0)
    clouds = []
    for f in range(len(frames)):
        rows = order[bounds[f]:bounds[f + 1]]
        if rows.size:
            views = _frame_views(rig, stripes.take(pa.array(rows)), floor)
            cloud, counts = reconstruct_stripe_frame(rig, views, f, rng, gate_probability, min_angle_rad, single_view)
            clouds.append(cloud)
            for k, v in counts.items():
                totals[k] += v
        if progress is not None:
            progress(f + 1, len(frames))
    cloud = PointCloud.concatenate(clouds)
    summary = dict(frames=len(frames), points=len(cloud), frames_with_plane=totals["plane"],
                   points_multi_view=totals["multi_view"], points_single_view=totals["single_view"],
                   pairs=totals["pairs"], pairs_off_plane=totals["off_plane_pairs"])
    return cloud, summary
