"""``inspect_cloud``: align a scan to its CAD model and measure the deviation of every point."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from scanrig.errors import InputError
from scanrig.geometry.checks import check_matrix, check_points
from scanrig.geometry.transform import RigidTransform
from scanrig.inspect.cad import check_cad_scale
from scanrig.inspect.closest import CadIndex, is_closed
from scanrig.inspect.coarse import OVERLAP_FRACTION, coarse_alignment, overlap
from scanrig.inspect.deviation import DeviationStats, deviation_stats, signed_deviation
from scanrig.inspect.icp import robust_icp
from scanrig.inspect.regions import Region, worst_regions

#: The fine ICP runs on at most this many points (its precision is already far below the noise).
ICP_MAX_POINTS = 20_000
#: Fewest points that can be aligned (a rigid transform has 6 parameters; a handful more to judge it).
MIN_ALIGN_POINTS = 20
#: Alignment gate: fraction of the points that must lie within OVERLAP_FRACTION x the part's size of
#: the CAD surface after the fit (30 % outliers and a few % of bumps still pass).
MIN_OVERLAP = 0.5


#: Below this ``constraint`` the fit leaves a motion free (a plane or a cylinder: ~0; a bracket
#: seen from one side: 0.02; a faceted cylinder with its end faces: 1e-4).
MIN_CONSTRAINT = 1e-3


class AlignmentError(InputError):
    """The cloud cannot be aligned to the CAD model (not this part, or too little of it)."""


@dataclass(frozen=True)
class Alignment:
    """How the cloud was put into the CAD frame.

    Attributes
    ----------
    method : str
        ``features`` (FPFH + RANSAC), ``multistart``, ``initial`` (the given transform) then
        ``+ robust ICP``; or ``none`` (``align=False``).
    residual_rms_m : float
        Weighted RMS of the final point-to-plane residuals of the points the fit kept, metres
        (NaN for ``none``).
    inlier_fraction : float
        Fraction of the ICP points with non-zero weight (NaN for ``none``).
    iterations : int
        Fine ICP iterations.
    constraint : float
        How well the kept points fix all six motions (see ``IcpResult.constraint``; NaN for
        ``none``); below :data:`MIN_CONSTRAINT` a motion is left free and a warning says so.
    """

    method: str
    residual_rms_m: float
    inlier_fraction: float
    iterations: int
    constraint: float

    def as_dict(self) -> dict:
        """JSON-ready: the residual and fraction are ``None`` when there was no fit (``none``)."""
        def number(x: float) -> float | None:
            return x if np.isfinite(x) else None
        return {"method": self.method, "residual_rms_m": number(self.residual_rms_m),
                "inlier_fraction": number(self.inlier_fraction), "iterations": self.iterations,
                "constraint": number(self.constraint)}


@dataclass(frozen=True)
class Inspection:
    """Result of :func:`inspect_cloud`.

    Attributes
    ----------
    cad_from_cloud : (4, 4) float array
        Maps cloud points into the CAD frame, metres.
    deviation_m : (N,) float array
        Signed deviation of each input point (input order), metres, positive outside the material
        (unsigned when ``signed`` is False).
    signed : bool
        False when the CAD is not closed (no inside/outside).
    stats : DeviationStats
        Summary over all points.
    alignment : Alignment
        The alignment and its residual.
    regions : tuple of Region
        Worst out-of-tolerance regions, CAD frame.
    warnings : tuple of str
        Plain-language warnings.
    seed : int
        The seed used.
    """

    cad_from_cloud: np.ndarray
    deviation_m: np.ndarray
    signed: bool
    stats: DeviationStats
    alignment: Alignment
    regions: tuple[Region, ...]
    warnings: tuple[str, ...]
    seed: int

    def points_cad(self, points_m: np.ndarray) -> np.ndarray:
        """The cloud ``(N, 3)`` mapped into the CAD frame, metres."""
        return points_m @ self.cad_from_cloud[:3, :3].T + self.cad_from_cloud[:3, 3]


def inspect_cloud(points_m: np.ndarray, cad: trimesh.Trimesh, *, tolerance_m: float, align: bool = True,
                  initial_cad_from_cloud: np.ndarray | None = None, seed: int = 0) -> Inspection:
    """Align a scan to the CAD model and measure the signed deviation of every point.

    Parameters
    ----------
    points_m : (N, 3) float array
        The scan, metres, any frame (outliers allowed).
    cad : trimesh.Trimesh
        The model, metres (see :func:`scanrig.inspect.cad.load_cad`).
    tolerance_m : float
        Tolerance on ``|deviation|``, metres (> 0).
    align : bool
        Find ``cad_from_cloud`` (coarse global alignment unless ``initial_cad_from_cloud`` is
        given, then robust point-to-plane ICP). False: the cloud is taken as already in the CAD
        frame (after ``initial_cad_from_cloud`` when given).
    initial_cad_from_cloud : (4, 4) float array, optional
        A starting transform (a rigid 4x4 in metres); it replaces the coarse alignment.
    seed : int
        Seeds every random draw (subsamples, RANSAC, random starts, CAD samples).

    Returns
    -------
    Inspection

    Raises
    ------
    ShapeError
        ``points_m`` is not ``(N, 3)``, or the initial transform is not a finite rigid 4x4.
    InputError
        Empty cloud, non-finite points, tolerance not > 0, or a CAD ~1000x larger or smaller
        than the cloud.
    AlignmentError
        ``align`` and the best fit brings less than :data:`MIN_OVERLAP` of the points within
        ``OVERLAP_FRACTION`` (0.2 %) of the part's size from the surface.
    """
    points_m = check_points(points_m, 3, "points_m")
    if len(points_m) == 0:
        raise InputError("points_m: the cloud is empty")
    if not np.all(np.isfinite(points_m)):
        raise InputError(f"points_m: {int(np.sum(~np.all(np.isfinite(points_m), axis=1)))} points are not finite")
    if not tolerance_m > 0:
        raise InputError(f"tolerance_m must be > 0, got {tolerance_m}")
    start = np.eye(4) if initial_cad_from_cloud is None else \
        RigidTransform.from_matrix(check_matrix(initial_cad_from_cloud, (4, 4), "initial_cad_from_cloud")).as_matrix()
    check_cad_scale(cad, points_m)
    rng = np.random.default_rng(seed)
    size_m = float(np.linalg.norm(cad.extents))
    index = CadIndex(cad, rng)
    warnings = []
    if align:
        alignment, cad_from_cloud = _align(points_m, index, start, size_m, initial_cad_from_cloud is None, rng)
    else:
        alignment, cad_from_cloud = Alignment("none", float("nan"), float("nan"), 0, float("nan")), start
    if alignment.constraint < MIN_CONSTRAINT:
        warnings.append("the scanned surface leaves a motion free (e.g. a single plane, or a surface of revolution): "
                        "cad_from_cloud is not determined along it; the deviations are")
    signed = is_closed(cad)
    if not signed:
        warnings.append("the CAD mesh is not closed (not watertight or inconsistently wound): deviations are "
                        "unsigned distances")
    points_cad = points_m @ cad_from_cloud[:3, :3].T + cad_from_cloud[:3, 3]
    deviation = signed_deviation(points_cad, index, signed)
    if not align:
        near = float(np.mean(np.abs(deviation) < OVERLAP_FRACTION * size_m))
        if near < MIN_OVERLAP:
            warnings.append(f"only {100 * near:.0f} % of the points lie within "
                            f"{1e3 * OVERLAP_FRACTION * size_m:.3g} mm of the CAD surface without alignment: "
                            "is the cloud in the CAD frame?")
    for a in (cad_from_cloud, deviation):
        a.setflags(write=False)
    return Inspection(cad_from_cloud, deviation, signed, deviation_stats(deviation, tolerance_m), alignment,
                      worst_regions(points_cad, deviation, tolerance_m, index, rng), tuple(warnings), seed)


def _align(points_m, index, start, size_m, coarse: bool, rng) -> tuple[Alignment, np.ndarray]:
    """Coarse (unless a start is given) then robust ICP on a subsample, gated by the overlap."""
    if len(points_m) < MIN_ALIGN_POINTS:
        raise AlignmentError(f"the cloud cannot be aligned to the CAD model: {len(points_m)} points, "
                             f"need at least {MIN_ALIGN_POINTS}")
    method = "initial"
    if coarse:
        found = coarse_alignment(points_m, index, size_m, rng)
        _gate(found.overlap, size_m)                      # hopeless already: spare the fine ICP
        start, method = found.cad_from_cloud, found.method
    sample = points_m if len(points_m) <= ICP_MAX_POINTS else \
        points_m[rng.choice(len(points_m), ICP_MAX_POINTS, replace=False)]
    fit = robust_icp(sample, index, start, size_m=size_m)
    _gate(overlap(sample, index, fit.cad_from_cloud, size_m), size_m)
    alignment = Alignment(f"{method} + robust ICP", fit.residual_rms_m, fit.inlier_fraction, fit.iterations,
                          fit.constraint)
    return alignment, fit.cad_from_cloud


def _gate(fraction: float, size_m: float) -> None:
    """Raise :class:`AlignmentError` when fewer than :data:`MIN_OVERLAP` of the points lie on the CAD."""
    if fraction < MIN_OVERLAP:
        raise AlignmentError(
            f"the cloud cannot be aligned to the CAD model: the best fit brings {100 * fraction:.0f} % of the points "
            f"within {1e3 * OVERLAP_FRACTION * size_m:.3g} mm of the surface (need {100 * MIN_OVERLAP:.0f} %); "
            "is it a scan of this part? give an initial transform to help")
