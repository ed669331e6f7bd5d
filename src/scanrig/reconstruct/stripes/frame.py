"""Points of one stripe frame: hypotheses, light plane, one point per detection, flags, precision."""

from __future__ import annotations

import numpy as np

from scanrig.geometry.uncertainty import sigma_from_covariance
from scanrig.reconstruct.chi2_gate import chi2_quantile
from scanrig.reconstruct.flags import Flag
from scanrig.reconstruct.points import PointCloud
from scanrig.reconstruct.stripes.accept import contradicted, greedy_unique
from scanrig.reconstruct.stripes.epipolar import frame_branches, hypotheses
from scanrig.reconstruct.stripes.plane_step import fit_frame_plane, gate_on_plane, three_view_pass
from scanrig.reconstruct.stripes.precision import sigma_across_stripe
from scanrig.reconstruct.stripes.single_view import single_view_points
from scanrig.reconstruct.stripes.solve import Observations, SolvedHypotheses, min_crossing_angle, solve


def reconstruct_stripe_frame(rig, views, frame_index: int, rng, gate_probability: float,
                             min_angle_rad: float, single_view: bool, branches=None, max_sigma_m: float = np.inf):
    """Points of one stripe frame (see :mod:`scanrig.reconstruct.stripes`).

    Parameters
    ----------
    rig : Rig
        The cameras, in the order of ``views``.
    views : list of StripeView
        The frame's detections per camera.
    frame_index : int
        Written in the ``frame`` column.
    rng : numpy.random.Generator
        For the robust plane fit.
    gate_probability, min_angle_rad
        χ² gate probability and smallest crossing angle (radians).
    single_view : bool
        Add the single-view points intersected with the plane.
    branches : dict, optional
        The frame's crossings (:func:`frame_branches`), computed when not given.
    max_sigma_m : float
        Points whose error across their stripe may exceed this (metres,
        :func:`~.precision.sigma_across_stripe`) are left out; ``numpy.inf`` keeps every point.

    Returns
    -------
    cloud : PointCloud
    counts : dict
        ``multi_view``, ``single_view`` points kept, ``imprecise`` points left out, ``pairs``
        (branches), ``off_plane_pairs`` (two-view hypotheses rejected) and ``plane`` (1 if the
        frame has one).
    """
    cams = rig.cameras
    counts = dict(multi_view=0, single_view=0, imprecise=0, off_plane_pairs=0, pairs=0, plane=0)
    branches = frame_branches(rig, views) if branches is None else branches
    hyps, crossed = _solve_hypotheses(cams, views, branches, min_angle_rad, counts)
    if not hyps:
        return PointCloud.empty(), counts

    # light plane from the consistent three-view hypotheses (or all pairs with two cameras)
    multi = [three_view_pass(h, gate_probability) for h in hyps]
    plane = fit_frame_plane(hyps, multi, rng)
    cand = []
    for h, s_multi in zip(hyps, multi):
        passed, p, cov, resid = gate_on_plane(cams, h, s_multi, plane, gate_probability, min_angle_rad)
        m = h.n_other
        counts["off_plane_pairs"] += int(((m == 1) & ~passed).sum())
        cand.append((h.ref, h.choice[passed], p[passed], cov[passed], resid[passed], m[passed]))
    counts["plane"] = int(plane is not None)

    # one detection, one point: the most precise consistent hypotheses first, then most views
    offsets = np.cumsum([0] + [len(v.q) for v in views])
    choice = np.concatenate([c[1] for c in cand])
    if len(choice) == 0 and plane is None:
        return PointCloud.empty(), counts
    p = np.concatenate([c[2] for c in cand])
    cov = np.concatenate([c[3] for c in cand])
    resid = np.concatenate([c[4] for c in cand])
    m = np.concatenate([c[5] for c in cand])
    ref = np.concatenate([np.full(len(c[1]), c[0]) for c in cand])
    # two-view points that a third camera contradicts: it sees the stripe right beside the point
    # but not through it (a third view that sees the stripe far away may be occluded there)
    clash = np.zeros(len(choice), bool)
    two = np.flatnonzero(m == 1)
    clash[two] = contradicted(cams, views, choice[two], p[two], cov[two], chi2_quantile(gate_probability, 1))
    counts["off_plane_pairs"] += int(clash.sum())
    choice, p, cov, resid, m, ref = (x[~clash] for x in (choice, p, cov, resid, m, ref))
    sigma = sigma_from_covariance(cov) if len(cov) else np.zeros(0)
    det_ids = np.where(choice >= 0, choice + offsets[:-1][None, :], -1)
    priority = np.lexsort((-m, sigma))
    order_rank = np.empty(len(priority), np.int64)
    order_rank[priority] = np.arange(len(priority))
    accepted = greedy_unique(det_ids, order_rank)
    choice, p, cov, resid, m, ref, sigma = (x[accepted] for x in (choice, p, cov, resid, m, ref, sigma))
    flags = _multi_view_flags(views, hyps, choice, ref)
    clouds = [PointCloud(p, sigma, m + 1, resid, np.full(len(p), frame_index), flags)]
    covs = [cov]

    if single_view and plane is not None:
        sigma_ref = np.median(sigma) if len(sigma) else 0.0
        used = np.zeros(offsets[-1], bool)
        used[det_ids[accepted][det_ids[accepted] >= 0]] = True
        lone, cov1 = single_view_points(cams, views, plane, crossed, used, sigma_ref, frame_index)
        clouds.append(lone)
        covs.append(cov1)
    cloud, cov = PointCloud.concatenate(clouds), np.concatenate(covs)
    # the precision cut; the single views lean on the multi-view points, never the reverse
    multi = cloud.n_views >= 2
    across = np.empty(len(cloud))
    across[multi] = sigma_across_stripe(cloud.p_world[multi], cov[multi], cloud.p_world[multi])
    across[~multi] = sigma_across_stripe(cloud.p_world[~multi], cov[~multi], cloud.p_world)
    precise = across <= max_sigma_m
    counts["multi_view"] = int((precise & (cloud.n_views >= 2)).sum())
    counts["single_view"] = int((precise & (cloud.n_views == 1)).sum())
    counts["imprecise"] = int((~precise).sum())
    return cloud.select(precise), counts


def _solve_hypotheses(cams, views, branches: dict, min_angle_rad: float, counts: dict):
    """The hypotheses of every reference camera, solved without the plane.

    Returns the list of :class:`SolvedHypotheses` (reference cameras with at least one) and, per
    camera, which detections have a crossing in another camera; adds the branches to
    ``counts["pairs"]``.
    """
    n_cams = len(cams)
    hyps = []
    crossed = [np.zeros(len(v.q), bool) for v in views]
    for i in range(n_cams):
        mine = {j: branches[i, j] for j in range(n_cams) if j != i and branches[i, j][0].size}
        for a, _ in mine.values():
            crossed[i][a] = True
            counts["pairs"] += int(a.size)
        if not mine:
            continue
        choice = hypotheses(n_cams, i, len(views[i].q), mine)
        if len(choice) == 0:
            continue
        obs = Observations(views, i, choice)
        p, cov, chi2, resid, ok = solve(cams, obs)
        ok &= min_crossing_angle(cams, obs, i) >= min_angle_rad
        hyps.append(SolvedHypotheses(i, choice, obs, p, cov, chi2, resid, ok))
    return hyps, crossed


def _multi_view_flags(views, hyps: list[SolvedHypotheses], choice: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``(N,)`` flags of accepted points: rejected candidates, saturation, dropped views.

    ``DROPPED_VIEW`` marks a point whose reference detection had crossings in a camera that the
    point does not use.
    """
    n_cams = len(views)
    flags = np.zeros(len(choice), np.uint16)
    for c, view in enumerate(views):
        use = choice[:, c] >= 0
        pick = np.maximum(choice[:, c], 0)
        if len(view.q):
            flags[use & (view.rank[pick] > 0)] |= np.uint16(Flag.REJECTED_CANDIDATES)
            flags[use & view.saturated[pick]] |= np.uint16(Flag.SATURATED)
    for i in range(n_cams):
        sel = ref == i
        for h in hyps:
            if h.ref != i:
                continue
            had = np.zeros((len(views[i].q), n_cams), bool)
            np.logical_or.at(had, h.choice[:, i], h.choice >= 0)
            dropped = had[choice[sel, i]] & (choice[sel] < 0)
            flags[np.flatnonzero(sel)[dropped.any(axis=1)]] |= np.uint16(Flag.DROPPED_VIEW)
    return flags
