"""Cross-camera correspondence of laser spots with rejection of secondary reflections.

In every frame each camera has a few spot candidates (the spot and, on shiny parts, its
reflections). A *hypothesis* picks at most one candidate per camera (or none: the camera is not
used) with at least two cameras. All hypotheses of all frames are triangulated at once with the
closed form, and each is scored by the χ² of its reprojection residuals normalised by the
detections' covariances (plus a floor for calibration error). A hypothesis is *consistent* when
its χ² passes the gate for ``2 n − 3`` degrees of freedom — for two views this is the epipolar
test, for more it also checks that all rays meet. Per frame the consistent hypothesis with the
most views wins, then the lowest χ²; views that disagree are thereby dropped. When another
consistent hypothesis gives a point that differs beyond the uncertainty of both, and either has
as many views or uses none of the winner's candidates (a second lit point, such as a secondary
reflection on a matte surface, seen consistently by two or more cameras), the frame is ambiguous
and flagged instead of guessed. Candidates that recur at one pixel frame after frame, more
densely than the scan around them (fixed features such as glints of room light on polished
metal, see :data:`~scanrig.reconstruct.candidates.STATIC_RADIUS_PX`), are never matched. The winners are
refined by Gauss–Newton (:func:`scanrig.triangulate`).

This is aniposelib's ``triangulate_possible`` made statistical (χ² gate instead of a pixel
threshold) and vectorised across frames (reference notes §3).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry.triangulation import MIN_TRIANGULATION_ANGLE_RAD, TriangulationInfo, triangulate
from scanrig.reconstruct.candidates import Candidates
from scanrig.reconstruct.chi2_gate import chi2_quantile
from scanrig.reconstruct.flags import Flag

#: Pixel noise added in quadrature to every detection's covariance before gating and in the
#: final covariance: the residual calibration error (a good calibration reaches 0.1 px RMS).
SIGMA_FLOOR_PX = 0.1
#: Probability that a correct hypothesis passes the χ² gate (and that two estimates of the same
#: point are judged equal in the ambiguity test).
GATE_PROBABILITY = 0.999


class FrameStatus(IntEnum):
    """Outcome of matching one frame."""

    MATCHED = 0
    #: Two consistent hypotheses disagree, with equal support or without a common candidate
    #: (two distinct lit points): flagged, not guessed.
    AMBIGUOUS = 1
    #: At least two cameras had candidates but no pair of them agrees.
    NO_AGREEMENT = 2
    #: Fewer than two cameras had a candidate.
    TOO_FEW_CAMERAS = 3


@dataclass(frozen=True)
class SpotMatches:
    """Result of :func:`match_spots`, one row per frame.

    Attributes
    ----------
    p_world : ndarray of shape (n_frames, 3)
        The frame's point (world, metres); NaN unless ``status`` is MATCHED or AMBIGUOUS.
    info : TriangulationInfo
        Quality of the refined winning hypothesis (n_frames rows).
    choice : ndarray of shape (n_frames, n_cams), int
        Candidate index used in each camera, −1 where the camera is not used.
    status : ndarray of shape (n_frames,), uint8
        :class:`FrameStatus`.
    flags : ndarray of shape (n_frames,), uint16
        :class:`~scanrig.reconstruct.flags.Flag` bits.
    """

    p_world: np.ndarray
    info: TriangulationInfo
    choice: np.ndarray
    status: np.ndarray
    flags: np.ndarray


def hypotheses(n_cams: int, k: int) -> np.ndarray:
    """Every choice of at most one of ``k`` candidates per camera using at least two cameras.

    Returns
    -------
    ndarray of shape (n_hyp, n_cams), int
        Candidate index per camera, −1 = camera not used.
    """
    all_tuples = np.array(list(itertools.product(range(-1, k), repeat=n_cams)), dtype=np.int64)
    return all_tuples[(all_tuples >= 0).sum(axis=1) >= 2]


def match_spots(
    rig,
    cand: Candidates,
    sigma_floor_px: float = SIGMA_FLOOR_PX,
    gate_probability: float = GATE_PROBABILITY,
    min_angle_rad: float = MIN_TRIANGULATION_ANGLE_RAD,
) -> SpotMatches:
    """Choose, per frame, the candidates that see the same spot, and triangulate them.

    Parameters
    ----------
    rig : Rig
        Cameras in the order of ``cand.cameras``.
    cand : Candidates
        Padded spot candidates (:func:`~scanrig.reconstruct.candidates.spot_candidates`).
    sigma_floor_px : float
        Calibration-error floor added in quadrature to each detection's sigma, pixels.
    gate_probability : float
        Probability mass of the χ² gate, in (0, 1).
    min_angle_rad : float
        Smallest triangulation angle of a hypothesis.

    Returns
    -------
    SpotMatches
    """
    cams = rig.cameras
    if len(cams) < 2:
        raise InputError(f"multi-view reconstruction needs at least 2 cameras, the rig has {len(cams)}")
    if list(rig.names) != list(cand.cameras):
        raise InputError(f"candidates are for cameras {cand.cameras}, the rig has {rig.names}")
    if not 0.0 < gate_probability < 1.0:
        raise InputError(f"gate_probability must be in (0, 1), got {gate_probability}")
    n_frames, n_cams, k = cand.q.shape[:3]
    floor = np.eye(2) * sigma_floor_px**2
    cov = cand.cov + floor

    dirs = np.full(cand.q.shape[:3] + (3,), np.nan)
    for i, cam in enumerate(cams):
        seen = np.all(np.isfinite(cand.q[:, i]), axis=-1)
        if seen.any():
            _, dirs[:, i][seen] = cam.rays(cand.q[:, i][seen])

    hyp = hypotheses(n_cams, k)
    usable = np.arange(k) < cand.count[..., None]  # (n_frames, n_cams, k)
    if cand.static is not None:
        usable &= ~cand.static  # fixed features are not laser light
    cam_idx = np.arange(n_cams)
    possible = np.all((hyp[None] < 0) | usable[:, cam_idx, np.maximum(hyp, 0)], axis=2)  # (n_frames, n_hyp)
    fi, hi = np.nonzero(possible)
    choice = hyp[hi]  # (M, n_cams)
    p, info = _triangulate_choices(rig, cand.q, cov, dirs, fi, choice, refine=False, min_angle_rad=min_angle_rad)
    dof = 2 * info.n_views.astype(np.int64) - 3
    gate = chi2_quantile(gate_probability, np.maximum(dof, 1))
    consistent = info.ok & (info.chi2 <= gate)

    fc, hc, pc, cov_c = fi[consistent], choice[consistent], p[consistent], info.cov[consistent]
    nv, x2 = info.n_views[consistent].astype(np.int64), info.chi2[consistent]
    order = np.lexsort((x2, -nv, fc))
    fc, hc, pc, cov_c, nv = fc[order], hc[order], pc[order], cov_c[order], nv[order]
    first = np.ones(fc.size, bool)
    first[1:] = fc[1:] != fc[:-1]
    best_row = np.flatnonzero(first)
    winner_of_row = np.cumsum(first) - 1  # index into best_row for every consistent row

    # Ambiguity: a rival whose point differs beyond both uncertainties and that either has as
    # many views, or shares no candidate with the winner. A disjoint rival is a second lit point
    # seen consistently by two or more cameras: a secondary reflection landing on a matte surface
    # is a real spot, and it is often seen by more cameras than the beam's own hit on the shiny
    # part, so the number of views does not tell which of the two the beam made.
    w = best_row[winner_of_row]
    delta = pc - pc[w]
    S = cov_c + cov_c[w]
    with np.errstate(invalid="ignore"):
        d2 = np.einsum("ni,ni->n", delta, np.linalg.solve(S, delta[..., None])[..., 0])
    disjoint = ~np.any((hc >= 0) & (hc == hc[w]), axis=1)
    rival = ((nv == nv[w]) | disjoint) & (d2 > chi2_quantile(gate_probability, 3))
    ambiguous_frames = np.unique(fc[rival])

    status = np.full(n_frames, FrameStatus.NO_AGREEMENT, np.uint8)
    status[usable.any(axis=2).sum(axis=1) < 2] = FrameStatus.TOO_FEW_CAMERAS
    matched_frames = fc[best_row]
    status[matched_frames] = FrameStatus.MATCHED
    status[ambiguous_frames] = FrameStatus.AMBIGUOUS
    final_choice = np.full((n_frames, n_cams), -1, np.int64)
    final_choice[matched_frames] = hc[best_row]

    frames_idx = np.arange(n_frames)
    p_final, info_final = _triangulate_choices(rig, cand.q, cov, dirs, frames_idx, final_choice,
                                               refine=True, min_angle_rad=min_angle_rad)
    status[(status == FrameStatus.MATCHED) & ~info_final.ok] = FrameStatus.NO_AGREEMENT
    flags = _flags(cand, usable.sum(axis=2), final_choice, status)
    return SpotMatches(p_final, info_final, final_choice, status, flags)


def _triangulate_choices(rig, q, cov, dirs, frame_idx, choice, refine, min_angle_rad):
    """Triangulate hypotheses given as (frame, candidate per camera) with −1 = unused."""
    n_cams = choice.shape[1]
    cam = np.arange(n_cams)
    pick = np.maximum(choice, 0)
    used = choice >= 0
    q_h = np.where(used[..., None], q[frame_idx[:, None], cam, pick], np.nan).transpose(1, 0, 2)
    cov_h = np.where(used[..., None, None], cov[frame_idx[:, None], cam, pick], np.nan).transpose(1, 0, 2, 3)
    dirs_h = np.where(used[..., None], dirs[frame_idx[:, None], cam, pick], np.nan).transpose(1, 0, 2)
    return triangulate(rig, q_h, cov_px=cov_h, refine=refine, min_angle_rad=min_angle_rad, dirs=dirs_h)


def _flags(cand: Candidates, count: np.ndarray, choice: np.ndarray, status: np.ndarray) -> np.ndarray:
    """Flag bits per frame; ``count`` is the number of usable (not fixed-feature) candidates."""
    used = choice >= 0
    flags = np.zeros(choice.shape[0], np.uint16)
    flags[np.any((count > 0) & ~used, axis=1)] |= np.uint16(Flag.DROPPED_VIEW)
    flags[np.any(used & (count > 1), axis=1)] |= np.uint16(Flag.REJECTED_CANDIDATES)
    sat = np.take_along_axis(cand.saturated, np.maximum(choice, 0)[..., None], axis=2)[..., 0]
    flags[np.any(used & sat, axis=1)] |= np.uint16(Flag.SATURATED)
    flags[status == FrameStatus.AMBIGUOUS] |= np.uint16(Flag.AMBIGUOUS)
    return flags
