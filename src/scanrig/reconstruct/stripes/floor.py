"""Calibration floor: extra pixel noise per camera and image radius, from three-view stripe points."""

from __future__ import annotations

import numpy as np

from scanrig.reconstruct.chi2_gate import chi2_quantile
from scanrig.reconstruct.correspondence import GATE_PROBABILITY
from scanrig.reconstruct.stripes.epipolar import frame_branches, hypotheses
from scanrig.reconstruct.stripes.solve import Observations, solve

#: Rings of image radius (px) on which the calibration floor is estimated.
FLOOR_BIN_PX = 50.0
#: Fewest unambiguous three-view points for the floor to be estimated (else the fixed floor).
FLOOR_MIN_SAMPLES = 200
#: A ring of a camera has its own floor only with this many samples, significantly (in standard
#: errors of a sign test) more of them above their χ² median than the noise model allows.
FLOOR_MIN_RING = 10
FLOOR_SIGNIFICANCE = 3.0
#: Robust re-fits of the floor, and the first (wide) gate, in multiples of the χ² gate.
FLOOR_ITERATIONS = 8
FLOOR_FIRST_GATE = 1000.0


def floor_samples(rig, views, branches=None):
    """Three-view (or more) hypotheses of one frame for :func:`estimate_calibration_floor`.

    Only unambiguous matches are used: every detection of the hypothesis has exactly one branch
    in each other camera of the hypothesis (so a reflection seen by one camera, which gives the
    other cameras' detections a second branch there, cannot enter), with all the reference's
    branches. Returns ``h (H, n_cams)`` — how much one px² of extra isotropic noise in each
    camera raises the expected χ² (``tr(R_cᵀ W R_c)`` with ``R = I − J H⁻¹ Jᵀ W`` the residual
    operator) — the χ², its degrees of freedom and each detection's radius (px) from its
    camera's principal point (NaN where unused).
    """
    cams = rig.cameras
    n_cams = len(cams)
    branches = frame_branches(rig, views) if branches is None else branches
    n_branches = {(i, j): np.bincount(a, minlength=len(views[i].q)) for (i, j), (a, _) in branches.items()}
    out = []
    for i in range(n_cams):
        mine = {j: branches[i, j] for j in range(n_cams) if j != i and branches[i, j][0].size}
        if len(mine) < 2:
            continue
        choice = hypotheses(n_cams, i, len(views[i].q), mine)
        used = (choice >= 0).sum(axis=1)
        most = np.zeros(len(views[i].q), int)
        np.maximum.at(most, choice[:, i], used)
        sel = (used == most[choice[:, i]]) & (used >= 3)
        for c1 in range(n_cams):
            for c2 in range(n_cams):
                if c1 != c2:
                    both = (choice[:, c1] >= 0) & (choice[:, c2] >= 0)
                    sel &= ~both | (n_branches[c1, c2][np.maximum(choice[:, c1], 0)] == 1)
        choice, used = choice[sel], used[sel]
        if len(choice) == 0:
            continue
        obs = Observations(views, i, choice)
        p, cov, chi2, _, ok = solve(cams, obs)
        H = len(choice)
        J = np.zeros((H, 2 * n_cams, 3))
        W = np.zeros((H, 2 * n_cams, 2 * n_cams))
        for c, cam in enumerate(cams):
            _, Jc = cam.project_with_point_jacobian(np.nan_to_num(p))
            J[:, 2 * c:2 * c + 2] = np.where(obs.used[c][:, None, None], np.nan_to_num(Jc), 0.0)
            W[:, 2 * c:2 * c + 2, 2 * c:2 * c + 2] = obs.W[c]
        R = np.eye(2 * n_cams) - J @ np.nan_to_num(cov) @ J.transpose(0, 2, 1) @ W
        h = np.stack([np.einsum("nki,nkl,nli->n", R[:, :, 2 * c:2 * c + 2], W, R[:, :, 2 * c:2 * c + 2])
                      for c in range(n_cams)], axis=1)
        radius = np.stack([np.where(obs.used[c], np.linalg.norm(obs.q[c] - cam.params[2:4], axis=1), np.nan)
                           for c, cam in enumerate(cams)], axis=1)
        ok &= np.all(np.isfinite(h), axis=1)
        out.append((h[ok], chi2[ok], (used[ok] - 2).astype(float), radius[ok]))
    return out


def estimate_calibration_floor(samples, n_cams: int, gate_probability: float = GATE_PROBABILITY,
                               bin_px: float = FLOOR_BIN_PX, max_radius_px: float = 2000.0):
    """Extra pixel noise per camera and image radius that makes the three-view χ² consistent.

    The calibration floor (``sigma_floor_px``) assumes the calibration is equally good everywhere.
    A calibration from target views that did not reach the image borders extrapolates its
    distortion there; stripes on the whole scene then meet errors of pixels, which two-view
    stripe points turn into millimetres. Points seen by three cameras reveal it: their χ² grows
    with the radius of their detections. The model is an isotropic variance ``s_c(r)²`` per
    camera ``c``, non-decreasing in the radius ``r`` (piecewise constant on ``bin_px`` rings), so
    ``E[χ²] = dof + Σ_c s_c(r_c)² h_c`` (:func:`floor_samples`) is linear in the non-negative ring
    increments: a non-negative least-squares fit, repeated with the hypotheses whose χ² fails the
    gate scaled by their predicted excess left out (wrong matches).

    Returns
    -------
    edges : ndarray of shape (n_bins,)
        Inner radius of each ring, px.
    s2 : ndarray of shape (n_cams, n_bins)
        Extra variance, px² (zeros when there are fewer than :data:`FLOOR_MIN_SAMPLES` samples).
    """
    from scipy.optimize import nnls

    edges = np.arange(0.0, max_radius_px, bin_px)
    n_bins = len(edges)
    s2 = np.zeros((n_cams, n_bins))
    if not samples:
        return edges, s2
    h = np.concatenate([x[0] for x in samples])
    chi2 = np.concatenate([x[1] for x in samples])
    dof = np.concatenate([x[2] for x in samples])
    radius = np.concatenate([x[3] for x in samples])
    if len(chi2) < FLOOR_MIN_SAMPLES:
        return edges, s2
    ring = np.minimum(np.searchsorted(edges, np.nan_to_num(radius, nan=-1.0), "right") - 1, n_bins - 1)
    A = np.zeros((len(chi2), n_cams * n_bins))
    for c in range(n_cams):
        for b in range(n_bins):
            A[:, c * n_bins + b] = np.where(ring[:, c] >= b, h[:, c], 0.0)
    # A ring gets its own increment only where its samples are significantly worse than the noise
    # model (sign test: under it half the χ² are below their median); else it keeps the inner
    # ring's value, so a few unlucky samples cannot raise the floor.
    above = chi2 > chi2_quantile(0.5, dof)
    live_ring = np.zeros((n_cams, n_bins), bool)
    for c in range(n_cams):
        seen = np.isfinite(radius[:, c])
        n = np.bincount(ring[seen, c], minlength=n_bins)[:n_bins]
        k = np.bincount(ring[seen, c], weights=above[seen], minlength=n_bins)[:n_bins]
        with np.errstate(invalid="ignore", divide="ignore"):
            z = (k - 0.5 * n) / (0.5 * np.sqrt(n))
        live_ring[c] = (n >= FLOOR_MIN_RING) & (z >= FLOOR_SIGNIFICANCE)
    live = np.flatnonzero(A.any(axis=0) & live_ring.ravel())
    if live.size == 0:
        return edges, s2
    gate = chi2_quantile(gate_probability, dof)
    keep = chi2 <= FLOOR_FIRST_GATE * gate
    for _ in range(FLOOR_ITERATIONS):
        if keep.sum() < FLOOR_MIN_SAMPLES:
            break
        t = np.zeros(A.shape[1])
        t[live], _ = nnls(A[keep][:, live], chi2[keep] - dof[keep])
        keep = chi2 <= gate * (1.0 + (A @ t) / dof)
        s2 = np.cumsum(t.reshape(n_cams, n_bins), axis=1)
    return edges, s2



def inflate_views(rig, views, edges: np.ndarray, s2: np.ndarray) -> None:
    """Add the estimated extra variance of each detection's camera and ring to its covariance.

    ``edges (n_bins,)`` and ``s2 (n_cams, n_bins)`` as returned by
    :func:`estimate_calibration_floor`; ``views`` (one frame, cameras in rig order) change in place.
    """
    for c, (cam, view) in enumerate(zip(rig.cameras, views)):
        if len(view.q):
            r = np.linalg.norm(view.q - cam.params[2:4], axis=1)
            view.inflate(s2[c][np.minimum(np.searchsorted(edges, r, "right") - 1, len(edges) - 1)])
