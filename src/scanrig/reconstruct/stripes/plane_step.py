"""The light-plane step of a stripe frame: fit the plane, then test every hypothesis against it."""

from __future__ import annotations

import numpy as np

from scanrig.geometry.uncertainty import sigma_from_covariance
from scanrig.reconstruct.chi2_gate import chi2_quantile
from scanrig.reconstruct.light_plane import MIN_PLANE_POINTS, fit_plane_robust, with_block_uncertainty
from scanrig.reconstruct.stripes.solve import SolvedHypotheses, solve

#: A two-view point is kept only if the plane makes it at most this many times more precise than
#: its two views do: the plane test sees errors at the scale of the views' own sigma.
PLANE_GAIN_MAX = 4.0
#: ... and only where the plane's own position is known at least this well, relative to the
#: standard deviation of the two-view point along the plane's normal: the plane χ² then flags
#: errors of a few of the point's own sigmas (``√10.8 · √2 σ ≈ 4.7 σ`` at the 0.999 gate).
PLANE_SIGMA_RATIO_MAX = 1.0


def three_view_pass(h: SolvedHypotheses, gate_probability: float) -> np.ndarray:
    """``(H,)`` hypotheses with three or more views that pass their χ² gate (``m − 1`` dof)."""
    m = h.n_other
    dof = np.maximum(m - 1, 1)
    return h.ok & (m >= 2) & (h.chi2 <= chi2_quantile(gate_probability, dof))


def fit_frame_plane(hyps: list[SolvedHypotheses], multi: list[np.ndarray], rng):
    """The frame's light plane with its block-jackknife uncertainty, or None.

    Fitted robustly to the three-view hypotheses that pass their gate (``multi``, one mask per
    item of ``hyps``) or, when they are fewer than ``MIN_PLANE_POINTS`` (two cameras), to every
    solved two-view hypothesis.
    """
    p_fit = np.concatenate([h.p[s] for h, s in zip(hyps, multi)])
    cov_fit = np.concatenate([h.cov[s] for h, s in zip(hyps, multi)])
    if len(p_fit) < MIN_PLANE_POINTS:
        pairs = [h.ok & ((h.choice >= 0).sum(axis=1) == 2) for h in hyps]
        p_fit = np.concatenate([h.p[s] for h, s in zip(hyps, pairs)])
        cov_fit = np.concatenate([h.cov[s] for h, s in zip(hyps, pairs)])
    if len(p_fit) < MIN_PLANE_POINTS:
        return None
    plane, inliers = fit_plane_robust(p_fit, None, rng, cov_m=cov_fit)
    if plane is not None:
        w = 1.0 / np.maximum(np.einsum("i,nij,j->n", plane.normal, cov_fit[inliers], plane.normal), 1e-24)
        plane = with_block_uncertainty(plane, p_fit[inliers], w)
    return plane


def gate_on_plane(cams, h: SolvedHypotheses, s_multi: np.ndarray, plane, gate_probability: float,
                  min_angle_rad: float):
    """Which hypotheses pass, with the plane as one more measurement where it measures depth.

    Where the reference ray crosses the plane at ``min_angle_rad`` or more, each hypothesis is
    re-solved with the plane and must pass the χ² gate with ``m`` degrees of freedom (those over
    that gate without the plane are not solved again: the plane's term only adds to χ²). A two-view
    point has no other test, so the test must have power at the point's own scale: the two views
    must locate it (the plane sharpens it at most :data:`PLANE_GAIN_MAX` times), and the plane must
    be known there (its position sigma at most :data:`PLANE_SIGMA_RATIO_MAX` times the point's
    sigma along the normal). Elsewhere, and without a plane, the three-view gate ``s_multi``
    decides.

    Returns
    -------
    passed : ndarray of shape (H,), bool
    p : ndarray of shape (H, 3)
        Points, re-solved with the plane where it was used.
    cov : ndarray of shape (H, 3, 3)
    residual_px : ndarray of shape (H,)
    """
    if plane is None:
        return s_multi, h.p, h.cov, h.residual_px
    m = h.n_other
    gate = chi2_quantile(gate_probability, m)
    # the plane measures depth only where the reference ray crosses it at an angle
    crossing = np.arcsin(np.clip(np.abs(h.obs.dirs[h.ref] @ plane.normal), 0.0, 1.0)) >= min_angle_rad
    # the plane's term only adds to χ², so a hypothesis over its gate without the plane is over it
    # with the plane too: only the others are solved again (on 8 cameras, 43 % of them)
    again = np.flatnonzero(h.ok & crossing & (h.chi2 <= gate))
    p2, cov2, chi2_2, resid2 = h.p.copy(), h.cov.copy(), np.full(len(m), np.inf), h.residual_px.copy()
    ok2 = np.zeros(len(m), bool)
    p2[again], cov2[again], chi2_2[again], resid2[again], ok2[again] = solve(cams, h.obs.take(again), plane,
                                                                            start=h.p[again])
    with_plane = h.ok & ok2 & crossing
    passed = with_plane & (chi2_2 <= gate)
    # a two-view point must be located by its own views, the plane only checking and
    # sharpening it: where the views leave it loose, the plane test cannot see errors
    # (a reflection's ray meets the plane somewhere) that the plane-made sigma would hide;
    # and the plane must be known where the point is: beyond its inliers, or about a stripe
    # that is a straight line in space (a flat floor: no point fixes the plane's tilt about it),
    # its position sigma grows to metres, the χ² passes any wrong match, and the views' own
    # sigma (tenths of a millimetre) hides an error of centimetres
    with np.errstate(invalid="ignore"):  # failed solutions have NaN covariances
        along_normal = np.sqrt(np.einsum("i,nij,j->n", plane.normal, h.cov, plane.normal))
        loose = (m == 1) & ~(sigma_from_covariance(h.cov) <= PLANE_GAIN_MAX * sigma_from_covariance(cov2))
        blind = (m == 1) & ~(plane.offset_sigma(np.nan_to_num(h.p)) <= PLANE_SIGMA_RATIO_MAX * along_normal)
    passed &= ~loose & ~blind
    p = np.where(with_plane[:, None], p2, h.p)
    cov = np.where(with_plane[:, None, None], cov2, h.cov)
    resid = np.where(with_plane, resid2, h.residual_px)
    passed |= ~crossing & s_multi
    return passed, p, cov, resid
