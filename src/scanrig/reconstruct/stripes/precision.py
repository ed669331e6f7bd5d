"""The precision cut: points whose error across their stripe may exceed the accuracy target.

The rule follows from the noise model. An error that a distance to the surface measures lies along
the surface normal. A point's ``sigma`` is the standard deviation along the largest axis of its
covariance, so it bounds the error along any direction, the normal included; but a stripe point
knows more about its normal. The stripe is where the light plane cuts the surface, so its 3-D
tangent ``t`` lies in the surface's tangent plane: the normal is perpendicular to ``t``. The
tangent alone does not give the normal (any direction of the plane perpendicular to ``t`` may be
it; the neighbouring stripes that would fix it are a frame's sweep step, ~10 mm, away, across edges
and curvature), but it bounds the error along it: the largest standard deviation of the
covariance projected on the plane perpendicular to ``t``. Where the covariance is longest along the
stripe — a detection's position along its stripe is not a measurement — that is much less than
``sigma``. The tangent comes from the frame's own points (principal direction of the neighbours
within :data:`TANGENT_RADIUS_M`); its angular error ``δ`` (the neighbours' RMS spread across their
line over the one along it, which includes the stripe's curvature) can turn the bound by ``δ``, so
``δ · sigma`` is added (:func:`sigma_across_stripe`). The tangents of multi-view points come from
the multi-view points only, so that adding the single-view points, which lean on them through
the plane, changes nothing of theirs.

Keeping only the points whose bound is at most ``σ_max`` therefore bounds the expected RMS distance
of the kept cloud to the true surface by ``σ_max``, whatever the mix of three-view, two-view and
single-view points and whatever the session; a cut relative to a typical sigma of the session
(the former rule: 1.5 × the median three-view sigma) bounds nothing in millimetres and moves with
the calibration's quality. So ``σ_max`` is the accuracy the scan must reach:
:data:`TARGET_SIGMA_M` unless the user sets it (``scanrig reconstruct --max-sigma-mm``). The bound is
conservative (distances to the truth are 0.6-0.85 of it on the simulated sessions). ``points.ply``
keeps ``sigma`` (the largest axis), which holds whatever the surface.

A rig that cannot reach the target — a long working distance, a poor calibration — keeps few
points; its summary says how many were left out (``points_imprecise``, ``max_sigma_mm``), and its
user sets the accuracy it needs instead. The cut bounds the noise, not gross errors: those are
the consistency tests' task (no point of the simulated sessions is 1 mm off even without a cut).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from scanrig.geometry.uncertainty import sigma_from_covariance
from scanrig.reconstruct.points import PointCloud

#: Accuracy target of a stripe point, metres: 0.1 mm, the RMS distance to the surface that issue 6
#: asks of stripe mode, imposed on each point's 1-sigma across its stripe.
TARGET_SIGMA_M = 1e-4
#: A point's 3-D stripe tangent is the principal direction of the frame's points within this
#: radius (metres; ~10-30 points on the simulated sessions), at most :data:`TANGENT_NEIGHBOURS`
#: of them and at least :data:`TANGENT_MIN_POINTS` (the point included), else ``sigma`` is used.
TANGENT_RADIUS_M = 4e-3
TANGENT_NEIGHBOURS = 32
TANGENT_MIN_POINTS = 5


def sigma_across_stripe(p_world: np.ndarray, cov: np.ndarray, stripe_m: np.ndarray) -> np.ndarray:
    """Bound on the standard deviation of each point's error across its stripe (see module doc).

    Parameters
    ----------
    p_world : ndarray of shape (N, 3)
        Points of one stripe frame, metres.
    cov : ndarray of shape (N, 3, 3)
        Their covariances, m².
    stripe_m : ndarray of shape (M, 3)
        The frame's points whose principal directions are the tangents, metres (``p_world``
        among them).

    Returns
    -------
    ndarray of shape (N,)
        ``σ⊥ + δ · sigma``, at most ``sigma`` (the largest axis), metres: ``σ⊥`` the largest
        standard deviation perpendicular to the estimated tangent, ``δ`` the tangent's angular
        error.
    """
    sigma = sigma_from_covariance(cov) if len(cov) else np.zeros(0)
    if len(p_world) == 0 or len(stripe_m) < TANGENT_MIN_POINTS:
        return sigma
    dist, idx = cKDTree(stripe_m).query(p_world, k=min(TANGENT_NEIGHBOURS, len(stripe_m)),
                                        distance_upper_bound=TANGENT_RADIUS_M)
    valid = np.isfinite(dist)
    count = valid.sum(axis=1)
    q = stripe_m[np.where(valid, idx, 0)]
    centre = np.einsum("nk,nki->ni", valid, q) / count[:, None]
    r = (q - centre[:, None]) * valid[:, :, None]
    eigval, eigvec = np.linalg.eigh(np.einsum("nki,nkj->nij", r, r))
    t = eigvec[:, :, 2]
    delta = np.sqrt(np.maximum(eigval[:, 1], 0.0) / np.maximum(eigval[:, 2], 1e-300))
    across = np.eye(3) - t[:, :, None] * t[:, None, :]
    sigma_perp = np.sqrt(np.maximum(np.linalg.eigvalsh(across @ cov @ across)[:, 2], 0.0))
    usable = (count >= TANGENT_MIN_POINTS) & (eigval[:, 2] > 0.0)
    return np.where(usable, np.minimum(sigma_perp + delta * sigma, sigma), sigma)


def split_by_precision(cloud: PointCloud, max_sigma_m: float) -> tuple[PointCloud, PointCloud]:
    """The points whose sigma is at most ``max_sigma_m`` (metres), and the others.

    The cut of the other modes (spots; the classic single-camera mode); multi-view stripe frames
    cut on :func:`sigma_across_stripe`.

    Parameters
    ----------
    cloud : PointCloud
        Points that passed their consistency tests.
    max_sigma_m : float
        Largest sigma kept, metres (``numpy.inf`` keeps every point).

    Returns
    -------
    kept, dropped : PointCloud
    """
    precise = cloud.sigma <= max_sigma_m
    return cloud.select(precise), cloud.select(~precise)
