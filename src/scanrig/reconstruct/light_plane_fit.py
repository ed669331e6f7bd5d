"""Light-plane calibration: the plane of a fixed laser from its stripe on the target at several poses.

Each pose gives stripe points on the target's plane. A flat target meets the light plane in a
straight line, so each pose's points off their own robust line are dropped first; then a
consensus plane through points of three different poses, scored by the median distance (no noise
scale assumed), seeds gated least-squares refits whose scale comes from the data; the plane's
uncertainty is widened by a jackknife over poses (errors are shared within a pose). Per-pose
residuals and warnings (too few poses, a tilt too loosely fixed) go with the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry.checks import check_points
from scanrig.geometry.uncertainty import MAD_TO_SIGMA
from scanrig.reconstruct.light_plane import (INLIER_SIGMAS, LightPlane, fit_plane, intersect_plane, plane_from,
                                             planes_through, with_jackknife_uncertainty)


@dataclass(frozen=True)
class PoseResidual:
    """How the stripe points of one target pose fit the calibrated light plane.

    Attributes
    ----------
    name : str
        The pose (the image's stem).
    n_points : int
        Stripe points of the pose on the target.
    n_inliers : int
        Those within the inlier gate of the plane.
    rms_m : float
        RMS distance of the inliers to the plane, metres (NaN without inliers).
    mean_m : float
        Their mean signed distance, metres: an error of the pose shifts the whole stripe.
    """

    name: str
    n_points: int
    n_inliers: int
    rms_m: float
    mean_m: float


@dataclass(frozen=True)
class LightPlaneFit:
    """A light plane calibrated from the stripe on the target at several poses.

    Attributes
    ----------
    plane : LightPlane
        The least-squares plane of the inliers, its uncertainty widened by the jackknife over
        poses (:func:`with_jackknife_uncertainty`).
    poses : tuple of PoseResidual
        Per pose, in input order.
    p_world : ndarray of shape (N, 3)
        The stripe points of all poses, concatenated in pose order, metres.
    pose_index : ndarray of shape (N,), int
        The pose of each point (index into ``poses``).
    inliers : ndarray of shape (N,), bool
    scale_m : float
        Standard deviation of the stripe points' distances, measured without the junk (see
        :func:`fit_light_plane`); the inlier gate is :data:`INLIER_SIGMAS` of it.
    warnings : tuple of str
        Poses too few or too alike to fix the plane, poses mostly off the plane.
    """

    plane: LightPlane
    poses: tuple
    p_world: np.ndarray
    pose_index: np.ndarray
    inliers: np.ndarray
    scale_m: float
    warnings: tuple = ()


#: Trials of the stripe-line search in each pose (pairs of points): with 30 % junk a pair is
#: clean with probability 0.49, so 100 pairs all fail with probability 0.51^100.
LINE_TRIALS = 100
#: Consensus trials of :func:`fit_light_plane`, each a plane through 3 points of 3 different
#: poses; with 10 % junk a trial is clean with probability 0.73, so 500 trials all fail with
#: probability 0.27^500.
CONSENSUS_TRIALS = 500
#: The consensus score (median absolute distance) is taken over at most this many points.
CONSENSUS_POINTS = 4000
#: Least-squares refits on the inliers, each with the scale re-measured, at most.
MAX_REFITS = 20
#: RMS of a unit normal distribution truncated at ±INLIER_SIGMAS (3): the inliers' RMS divided by
#: it estimates the scale without the junk outside the gate, which the median does not ignore.
TRUNCATED_SD = 0.98658
#: Floor of the scale, metres (noise-free points).
MIN_SCALE_M = 1e-9
#: Fewest poses for the jackknife over poses; with fewer the sigma is from the points alone.
MIN_JACKKNIFE_POSES = 4
#: Fewer poses than this earn a warning (the jackknife's own spread is wide).
RECOMMENDED_POSES = 4
#: Warn when the plane's tilt is known to worse than this, degrees (1 sigma): 0.05 deg moves the
#: plane by 0.13 mm at 150 mm from the points' centroid.
TILT_WARN_DEG = 0.05
#: The inliers lie along one line (the target in one plane at every pose: no plane is defined)
#: when fewer than MIN_OFF_LINE_FRACTION of them are farther from their principal line than
#: MIN_LINE_SCALES noise scales or MIN_LINE_M metres, whichever is larger.
MIN_LINE_SCALES = 10.0
MIN_LINE_M = 1e-3
MIN_OFF_LINE_FRACTION = 0.1
#: Warn about a pose when less than this fraction of its stripe points are inliers.
MIN_POSE_INLIER_FRACTION = 0.5


def fit_light_plane(points_by_pose, rng: np.random.Generator, names=None,
                    trials: int = CONSENSUS_TRIALS) -> LightPlaneFit:
    """Robust light plane through the stripe points of several target poses.

    The laser meets a flat target in a straight line: in each pose the points off that pose's
    robust 3-D line are junk (texture edges, reflections) and are left out. Then a consensus
    search (planes through 3 points of 3 different poses, scored by the median absolute distance
    of all points, so no scale is assumed) finds the plane the majority supports; then the scale
    is measured from the data (first ``MAD_TO_SIGMA`` × the median absolute distance, then the
    inliers' RMS distance over :data:`TRUNCATED_SD`), the points within :data:`INLIER_SIGMAS` of
    it are refitted by least squares, and both are iterated until the inliers no longer change.
    The plane's uncertainty is that of the least-squares fit on the inliers, widened where a
    delete-one-pose jackknife shows more:
    points of one pose share that pose's error (its target plane), which independent-error
    formulas would divide by the square root of their number. With ``g`` poses the jackknife
    variance is itself known only to ``g - 1`` degrees of freedom, so an error divided by its
    sigma follows Student's t, whose variance is ``(g - 1) / (g - 3)``; the jackknife variances
    are multiplied by that factor so the normalised errors have unit spread (measured over seeds:
    ``benchmarks/bench_light_plane.py``). With fewer than :data:`MIN_JACKKNIFE_POSES` poses the
    sigma is that of independent errors and a warning says so. The calibration's own share of the
    uncertainty (common to all poses) is added by :func:`with_sampled_uncertainty`.

    Parameters
    ----------
    points_by_pose : sequence of ndarray of shape (n_k, 3)
        Stripe points on the target at each pose, world frame, metres.
    rng : numpy.random.Generator
        For the consensus samples.
    names : sequence of str, optional
        Pose names for the residuals and warnings (default ``"0"``, ``"1"`` ...).
    trials : int
        Consensus trials.

    Returns
    -------
    LightPlaneFit

    Raises
    ------
    InputError
        Fewer than 2 poses with stripe points, points of all poses along one line (the target in
        one plane at every pose), or fewer than 2 poses with most of their points on the plane.
    """
    names = [str(k) for k in range(len(points_by_pose))] if names is None else [str(n) for n in names]
    if len(names) != len(points_by_pose):
        raise InputError(f"names must have one entry per pose, got {len(names)} for {len(points_by_pose)} poses")
    parts = [check_points(p, 3, f"points_by_pose[{k}]") for k, p in enumerate(points_by_pose)]
    counts = np.array([len(p) for p in parts])
    p = np.concatenate(parts)
    pose = np.repeat(np.arange(len(parts)), counts)
    on_line = np.concatenate([_stripe_line_inliers(part, rng) for part in parts])
    n_used = int(np.count_nonzero(np.bincount(pose[on_line], minlength=len(parts)) >= 3))
    if n_used < 2:
        raise InputError(f"a light plane needs the stripe on the target at 2 or more poses, got {n_used}")
    plane = _consensus_plane(p[on_line], pose[on_line], rng, trials)
    plane, on_plane, scale = _gated_refits(p[on_line], plane, lambda m, x: np.abs(m.distance(x)), fit_plane)
    inliers = np.zeros(len(p), bool)
    inliers[np.flatnonzero(on_line)[on_plane]] = True
    # (the jackknife below changes the plane's sigmas, not the plane: these residuals stay)
    residuals = _pose_residuals(plane, p, pose, inliers, names)
    _check_poses_agree(residuals)
    rel = p[inliers] - p[inliers].mean(axis=0)
    along = np.linalg.eigh(rel.T @ rel)[1][:, -1]
    off_line_m = np.linalg.norm(rel - np.outer(rel @ along, along), axis=1)
    if np.mean(off_line_m > max(MIN_LINE_SCALES * scale, MIN_LINE_M)) < MIN_OFF_LINE_FRACTION:
        raise InputError(f"the stripe points of all {n_used} poses lie along one line (the target in one "
                         f"plane at every pose?): move the target to other distances and tilts between shots")
    g = len(np.unique(pose[inliers]))
    if g >= MIN_JACKKNIFE_POSES:
        plane = with_jackknife_uncertainty(plane, p[inliers], np.ones(int(inliers.sum())), pose[inliers],
                                           variance_factor=(g - 1) / (g - 3))
    shifts = _pose_shifts(plane, p[on_line], pose[on_line], len(parts))
    return LightPlaneFit(plane, residuals, p, pose, inliers, scale, _warnings(plane, residuals, shifts, scale))


def _gated_refits(p: np.ndarray, model, distance_of, fit):
    """Alternate a gate at :data:`INLIER_SIGMAS` scales and a least-squares refit on the inliers.

    The first scale is ``MAD_TO_SIGMA`` × the median distance of all points to ``model``; later
    ones are the inliers' RMS distance over :data:`TRUNCATED_SD`, which the junk outside the gate
    no longer inflates. Returns the model, the inlier mask ``(N,)`` and the scale (metres).
    """
    distance = distance_of(model, p)
    scale = max(MAD_TO_SIGMA * float(np.median(distance)), MIN_SCALE_M)
    inliers = np.zeros(len(p), bool)
    for _ in range(MAX_REFITS):
        new = distance <= INLIER_SIGMAS * scale
        if np.array_equal(new, inliers) or new.sum() < 3:
            break
        inliers = new
        model = fit(p[inliers])
        distance = distance_of(model, p)
        scale = max(float(np.sqrt(np.mean(distance[inliers] ** 2))) / TRUNCATED_SD, MIN_SCALE_M)
    return model, inliers, scale


def _line_distance(line, p: np.ndarray) -> np.ndarray:
    """Distances ``(N,)`` of points to a line ``(point (3,), unit direction (3,))``, metres."""
    rel = p - line[0]
    return np.linalg.norm(rel - np.outer(rel @ line[1], line[1]), axis=1)


def _fit_line(p: np.ndarray):
    """Least-squares 3-D line: the centroid and the principal axis."""
    centre = p.mean(axis=0)
    rel = p - centre
    return centre, np.linalg.eigh(rel.T @ rel)[1][:, -1]


def _stripe_line_inliers(p: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Mask ``(n,)`` of one pose's points on its stripe line.

    The laser meets a flat target in a straight line, so points of the target off that line
    (texture edges, reflections, another light) are junk whatever the plane. The line through two
    points with the least median distance of all, then :func:`_gated_refits`. A pose with fewer
    than 3 points has none.
    """
    n = len(p)
    if n < 3:
        return np.zeros(n, bool)
    pairs = rng.integers(0, n, (LINE_TRIALS, 2))
    direction = p[pairs[:, 1]] - p[pairs[:, 0]]
    length = np.linalg.norm(direction, axis=1)
    ok = length > 0
    if not np.any(ok):
        return np.zeros(n, bool)
    starts, direction = p[pairs[ok, 0]], direction[ok] / length[ok, None]
    rel = p[None, :, :] - starts[:, None, :]
    along = np.einsum("tnk,tk->tn", rel, direction)
    distance = np.linalg.norm(rel - along[:, :, None] * direction[:, None, :], axis=2)
    best = int(np.argmin(np.median(distance, axis=1)))
    _, inliers, _ = _gated_refits(p, (starts[best], direction[best]), _line_distance, _fit_line)
    return inliers


def _consensus_plane(p: np.ndarray, pose: np.ndarray, rng: np.random.Generator, trials: int) -> LightPlane:
    """The plane through 3 points of 3 different poses with the least median absolute distance."""
    labels, start, count = np.unique(pose, return_index=True, return_counts=True)
    if len(labels) >= 3:
        pick = np.argsort(rng.random((trials, len(labels))), axis=1)[:, :3]
    else:  # two poses: two points from one, one from the other
        pick = np.column_stack([np.zeros(trials, int), np.ones(trials, int), rng.integers(0, 2, trials)])
    idx = start[pick] + (rng.random(pick.shape) * count[pick]).astype(int)
    normals, offsets = planes_through(p[idx])
    if len(normals) == 0:
        raise InputError("the stripe points of all poses lie along one line: move the target to other "
                         "distances and tilts between shots")
    scored = p if len(p) <= CONSENSUS_POINTS else p[rng.choice(len(p), CONSENSUS_POINTS, replace=False)]
    best = int(np.argmin(np.median(np.abs(scored @ normals.T - offsets), axis=0)))
    return LightPlane(normals[best], float(offsets[best]), p.mean(axis=0), np.eye(3)[:2], np.ones(2), 0.0, len(p))


def _pose_residuals(plane: LightPlane, p, pose, inliers, names) -> tuple:
    """:class:`PoseResidual` of every pose (vectorised over points)."""
    n_poses = len(names)
    d = plane.distance(p)
    n_points = np.bincount(pose, minlength=n_poses)
    n_in = np.bincount(pose[inliers], minlength=n_poses)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.bincount(pose[inliers], d[inliers] ** 2, n_poses) / n_in)
        mean = np.bincount(pose[inliers], d[inliers], n_poses) / n_in
    return tuple(PoseResidual(name, int(n_points[k]), int(n_in[k]), float(rms[k]), float(mean[k]))
                 for k, name in enumerate(names))


def _agrees(r: PoseResidual) -> bool:
    """Whether most of a pose's stripe points (and 3 at least) lie on the plane."""
    return r.n_inliers >= max(3, MIN_POSE_INLIER_FRACTION * r.n_points)


def _check_poses_agree(residuals) -> None:
    """Raise unless 2 poses or more have most of their stripe points on the plane: a plane through
    one pose's line and a few points of the others is not the laser's."""
    if sum(_agrees(r) for r in residuals) >= 2:
        return
    counts = ", ".join(f"pose {r.name}: {r.n_inliers} of {r.n_points}" for r in residuals if r.n_points)
    raise InputError(f"the stripe points of fewer than 2 poses lie on one plane ({counts} points on it): a wrong "
                     f"target pose, or another light on the target? The poses must show one laser's stripe")


def _pose_shifts(plane: LightPlane, p: np.ndarray, pose: np.ndarray, n_poses: int) -> np.ndarray:
    """Per pose, the median signed distance of its points ``p (N, 3)`` (of poses ``pose (N,)``) to
    ``plane`` and their robust spread about it (``MAD_TO_SIGMA`` × the median absolute deviation):
    ``(n_poses, 2)`` metres, NaN for a pose without points."""
    d = plane.distance(p)
    out = np.full((n_poses, 2), np.nan)
    for k in np.unique(pose):  # a handful of poses; each median is vectorised over its points
        dk = d[pose == k]
        median = float(np.median(dk))
        out[k] = median, MAD_TO_SIGMA * float(np.median(np.abs(dk - median)))
    return out


def _warnings(plane: LightPlane, residuals, shifts: np.ndarray, scale_m: float) -> tuple:
    """Poses too few or too alike to fix the plane; poses mostly off the plane, and whether their
    stripe lies off it (its median distance beyond the gate) or scatters about it (``shifts``:
    :func:`_pose_shifts`; ``scale_m``: the inlier scale of all poses)."""
    out = []
    used = [r for r in residuals if r.n_inliers > 0]
    if len(used) < RECOMMENDED_POSES:
        out.append(f"only {len(used)} poses carry the stripe: the plane's sigma assumes independent point errors "
                   f"and may be too small; shoot 6 or more poses at different distances and tilts")
    tilt_deg = float(np.degrees(plane.tilt_sigma_rad().max()))
    if tilt_deg > TILT_WARN_DEG:
        out.append(f"the plane's tilt is known only to {tilt_deg:.3f} deg (1 sigma): the poses are too few or "
                   f"too alike; add poses at other distances and tilts")
    for r, (median_m, spread_m) in zip(residuals, shifts):
        if not r.n_points or _agrees(r):
            continue
        head = f"pose {r.name}: only {r.n_inliers} of {r.n_points} stripe points lie on the plane"
        if np.isfinite(median_m) and abs(median_m) <= INLIER_SIGMAS * scale_m:
            out.append(f"{head}; they scatter {1e3 * spread_m:.3f} mm about it, against {1e3 * scale_m:.3f} mm over "
                       f"all poses (the stripe along the print's edges, or seen at a grazing angle?)")
        else:
            off = "" if not np.isfinite(median_m) else f"; its stripe lies {1e3 * median_m:+.3f} mm off it"
            out.append(f"{head}{off} (a wrong target pose, or another light on the target?)")
    return tuple(out)


def calibrate_light_plane(camera, target_planes, stripe_pixels, rng: np.random.Generator,
                          names=None) -> LightPlaneFit:
    """The light plane of a fixed laser from its stripe on a calibration target at several poses.

    Each pose gives the target's plane (from the calibration) and the stripe's pixels on it; the
    pixels' rays meet the target plane in 3-D points of the light plane, and the plane is fitted
    to all of them robustly (:func:`fit_light_plane`).

    Parameters
    ----------
    camera : Camera
        The calibrated camera that sees the stripe.
    target_planes : sequence of (normal (3,), offset float)
        The target's plane at each pose, world frame (``normal · x = offset``).
    stripe_pixels : sequence of ndarray of shape (n_k, 2)
        Stripe centres on the target in each pose, pixels.
    rng : numpy.random.Generator
        For the robust fit.
    names : sequence of str, optional
        Pose names.

    Raises
    ------
    InputError
        If the lists differ in length, fewer than 2 poses carry stripe points or the points do
        not define a plane (all poses in one plane).
    """
    if len(target_planes) != len(stripe_pixels):
        raise InputError(f"target_planes and stripe_pixels must have the same length, got "
                         f"{len(target_planes)} and {len(stripe_pixels)}")
    points = []
    for (normal, offset), q in zip(target_planes, stripe_pixels):
        centers, dirs = camera.rays(np.asarray(q, np.float64).reshape(-1, 2))
        p, _ = intersect_plane(centers, dirs, plane_from(normal, offset))
        points.append(p[np.all(np.isfinite(p), axis=1)])
    return fit_light_plane(points, rng, names)
