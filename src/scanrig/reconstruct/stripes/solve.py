"""Maximum-likelihood points of stripe hypotheses, with covariance and χ² (Gauss–Newton on pixels)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from scanrig.geometry.uncertainty import inv_sym3, pixel_weights
from scanrig.reconstruct.stripes.epipolar import MERGE_PX

#: Gauss–Newton steps after the linear start (the start is within the noise; two steps reach the
#: optimum to well below it, the third makes the covariance and χ² those of the optimum).
GN_STEPS = 3


class Observations:
    """Per-camera pixel observations of hypotheses: ``q (n_cams, H, 2)``, weights ``W (n_cams, H, 2, 2)``.

    The reference detection has its full inverse covariance; a matched detection only the
    weight across its stripe, ``n nᵀ / σ⊥²``. Also the normalised-coordinate rows of the linear
    start and the ray directions.
    """

    def __init__(self, views, ref: int, choice: np.ndarray):
        n_cams, H = len(views), len(choice)
        self.used = choice.T >= 0  # (n_cams, H)
        self.rows_of = [np.flatnonzero(u) for u in self.used]  # per camera, the hypotheses using it
        self.q = np.zeros((n_cams, H, 2))
        self.W = np.zeros((n_cams, H, 2, 2))
        self.D = np.zeros((n_cams, H, 2, 2))  # rᵀ D r: squared residual distance (px²)
        self.T = np.zeros((n_cams, H, 2))  # stripe tangent of matched detections (0 for the reference)
        self.dirs = np.full((n_cams, H, 3), np.nan)
        self.rows = []  # (camera, a (H, k, 3) normalised rows, sigma_norm (H,))
        for c, view in enumerate(views):
            pick = np.maximum(choice[:, c], 0)
            use = self.used[c]
            if not use.any():
                continue
            q = view.q[pick]
            self.q[c] = np.where(use[:, None], q, 0.0)
            self.dirs[c] = np.where(use[:, None], view.dirs[pick], np.nan)
            focal = np.sqrt(view.cam.params[0] * view.cam.params[1])
            if c == ref:
                W = pixel_weights(view.cov[pick])
                x = view.xh[pick]
                r1 = np.c_[np.ones(H), np.zeros(H), -x[:, 0]]
                r2 = np.c_[np.zeros(H), np.ones(H), -x[:, 1]]
                rows = np.stack([r1, r2], axis=1)
                sig = np.sqrt(0.5 * np.trace(view.cov[pick], axis1=1, axis2=2)) / focal
                D = np.broadcast_to(np.eye(2), (H, 2, 2))
            else:
                nrm = view.normal[pick]
                W = nrm[:, :, None] * nrm[:, None, :] / view.var_perp[pick][:, None, None]
                rows = view.lines()[pick][:, None, :]
                sig = np.sqrt(view.var_perp[pick]) / focal
                D = nrm[:, :, None] * nrm[:, None, :]
                self.T[c] = np.where(use[:, None], view.tangent[pick], 0.0)
            self.W[c] = np.where(use[:, None, None], W, 0.0)
            self.D[c] = np.where(use[:, None, None], D, 0.0)
            self.rows.append((c, rows, np.where(use, sig, np.nan)))

    def take(self, index: np.ndarray) -> Observations:
        """The observations of the hypotheses ``index`` ``(k,)`` (int), in that order."""
        out = object.__new__(Observations)
        out.used = self.used[:, index]
        out.rows_of = [np.flatnonzero(u) for u in out.used]
        out.q, out.W, out.D, out.T, out.dirs = (a[:, index] for a in (self.q, self.W, self.D, self.T, self.dirs))
        out.rows = [(c, rows[index], sig[index]) for c, rows, sig in self.rows]
        return out


def solve(cams, obs: Observations, plane=None, start=None):
    """Maximum-likelihood points of hypotheses (Gauss–Newton on pixels, optional plane term).

    Returns
    -------
    p : (H, 3), cov : (H, 3, 3), chi2 : (H,), residual_px : (H,), ok : (H,) bool
    """
    H = obs.q.shape[1]
    p = _linear_start(cams, obs) if start is None else start.copy()
    if plane is not None:
        w_plane = 1.0 / np.maximum(plane.offset_sigma(_finite(p)), 1e-9) ** 2
    with np.errstate(invalid="ignore", over="ignore"):  # diverged hypotheses end as not ok
        for it in range(GN_STEPS + 1):
            # the steps need only the normal equations; the last pass, at the solution, gives the
            # covariance, χ², the residuals and the checks
            final = it == GN_STEPS
            A = np.zeros((H, 3, 3))
            g = np.zeros((H, 3))
            if final:
                chi2 = np.zeros(H)
                rsum = np.zeros(H)
                along = np.zeros(H)
                front = np.ones(H, bool)
            p_finite = _finite(p)
            for c, cam in enumerate(cams):
                # only the hypotheses that use this camera (about half of them on an 8-camera rig)
                rows = obs.rows_of[c]
                if rows.size == 0:
                    continue
                q_hat, J = cam.project_with_point_jacobian(p_finite[rows])
                r = obs.q[c, rows] - _finite(q_hat)
                J = _finite(J)
                W = obs.W[c, rows]
                Wr = np.einsum("nij,nj->ni", W, r)
                A[rows] += J.transpose(0, 2, 1) @ (W @ J)  # JᵀWJ: matmul, a quarter of einsum's time
                if not final:
                    g[rows] += np.einsum("nki,nk->ni", J, Wr)
                else:
                    front[rows] &= np.all(np.isfinite(q_hat), axis=1)
                    chi2[rows] += np.einsum("ni,ni->n", r, Wr)
                    # residual as a distance: full for the reference, across the stripe for the others
                    rsum[rows] += np.einsum("ni,nij,nj->n", r, obs.D[c, rows], r)
                    along[rows] = np.fmax(along[rows], np.abs(np.einsum("ni,ni->n", obs.T[c, rows], r)))
            if plane is not None:
                rp = plane.offset - p_finite @ plane.normal
                A += w_plane[:, None, None] * plane.normal[None, :, None] * plane.normal[None, None, :]
                if not final:
                    g += (w_plane * rp)[:, None] * plane.normal
                else:
                    chi2 += w_plane * rp**2
            cov, singular = inv_sym3(A)
            if final:
                break
            p = p + np.einsum("nij,nj->ni", cov, g)
        n_views = obs.used.sum(axis=0)
        residual_px = np.sqrt(np.maximum(rsum, 0.0) / np.maximum(n_views, 1))
    ok = front & ~singular & np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(cov), axis=(1, 2))
    ok &= np.isfinite(chi2)
    # the point must project onto the piece of stripe that was matched (the line constraint is
    # local: far along the stripe from the matched detection it says nothing)
    ok &= along <= MERGE_PX
    return p, cov, chi2, residual_px, ok


def _finite(x: np.ndarray) -> np.ndarray:
    """``np.nan_to_num(x)`` (NaN to 0, ±inf to the largest floats), or ``x`` itself where all of it is
    finite: one pass instead of nan_to_num's four on the usual all-finite arrays."""
    return x if np.isfinite(x).all() else np.nan_to_num(x)


def _linear_start(cams, obs: Observations):
    """Weighted linear least squares in normalised coordinates (two passes: depths, then weights)."""
    H = obs.q.shape[1]
    p = np.zeros((H, 3))
    depth = {c: np.ones(H) for c, _, _ in obs.rows}
    for _ in range(2):
        A = np.zeros((H, 3, 3))
        g = np.zeros((H, 3))
        for c, rows, sig in obs.rows:
            R, t = cams[c].cam_from_world.R, cams[c].cam_from_world.t
            a = rows @ R  # (H, k, 3)
            rhs = -(rows @ t)  # (H, k)
            w = np.nan_to_num(1.0 / (sig * depth[c]) ** 2)  # NaN (unused) -> 0
            A += np.einsum("n,nki,nkj->nij", w, a, a)
            g += np.einsum("n,nki,nk->ni", w, a, rhs)
        inv, _ = inv_sym3(A)
        p = np.einsum("nij,nj->ni", inv, g)
        for c, _, _ in obs.rows:
            z = p @ cams[c].cam_from_world.R[2] + cams[c].cam_from_world.t[2]
            depth[c] = np.where(np.isfinite(z) & (z > 0), z, 1.0)
    return p


def min_crossing_angle(cams, obs: Observations, ref: int) -> np.ndarray:
    """Smallest angle between the reference ray and the stripe planes of the matched cameras, rad.

    A matched detection constrains the point to the plane through its camera's centre and its
    stripe's local line; where the reference ray runs within a small angle of that plane (the
    epipolar line along the stripe, as for two cameras that both see the light sheet edge-on),
    the depth it gives is unusable, like two nearly parallel rays.
    """
    d_ref = obs.dirs[ref]
    worst = np.full(d_ref.shape[0], np.inf)
    for c, rows, _ in obs.rows:
        if c == ref:
            continue
        normal = rows[:, 0, :] @ cams[c].cam_from_world.R  # plane normal in the world frame
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        angle = np.arcsin(np.clip(np.abs(np.einsum("ni,ni->n", normal, d_ref)), 0.0, 1.0))
        worst = np.where(obs.used[c], np.fmin(worst, angle), worst)
    return worst



class SolvedHypotheses(NamedTuple):
    """The hypotheses of one reference camera in one frame, solved without the light plane."""

    #: Reference camera index.
    ref: int
    #: ``(H, n_cams)`` detection index per camera, ``-1`` unused.
    choice: np.ndarray
    obs: Observations
    #: ``(H, 3)`` points, world frame, metres.
    p: np.ndarray
    #: ``(H, 3, 3)`` their covariances, m².
    cov: np.ndarray
    #: ``(H,)`` χ² with ``m − 1`` degrees of freedom for ``m`` other cameras.
    chi2: np.ndarray
    #: ``(H,)`` RMS residual distance per view, px.
    residual_px: np.ndarray
    #: ``(H,)`` solved, in front of the cameras, on the matched pieces of stripe, at an angle.
    ok: np.ndarray

    @property
    def n_other(self) -> np.ndarray:
        """``(H,)`` number ``m`` of other cameras each hypothesis uses."""
        return (self.choice >= 0).sum(axis=1) - 1
