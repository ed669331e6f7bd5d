"""Signed deviation of each scanned point from the CAD surface, and its summary statistics."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.inspect.closest import CadIndex


@dataclass(frozen=True)
class DeviationStats:
    """Summary of the deviations of all points (outliers included, as a metrology report shows them).

    Attributes
    ----------
    n_points : int
    rms_m, mean_m : float
        RMS and mean of the (signed) deviations, metres.
    p95_abs_m, max_abs_m : float
        95th percentile and maximum of the absolute deviations, metres.
    tolerance_m : float
        The tolerance, metres.
    within_tolerance : float
        Fraction of the points with ``|deviation| <= tolerance_m``.
    """

    n_points: int
    rms_m: float
    mean_m: float
    p95_abs_m: float
    max_abs_m: float
    tolerance_m: float
    within_tolerance: float

    def as_dict(self) -> dict:
        return {"n_points": self.n_points, "rms_m": self.rms_m, "mean_m": self.mean_m, "p95_abs_m": self.p95_abs_m,
                "max_abs_m": self.max_abs_m, "tolerance_m": self.tolerance_m,
                "within_tolerance": self.within_tolerance}


def signed_deviation(points_cad_m: np.ndarray, index: CadIndex, signed: bool) -> np.ndarray:
    """Distance of each point to the CAD surface, positive outside the material.

    Parameters
    ----------
    points_cad_m : (N, 3) float array
        Points in the CAD frame, metres.
    index : CadIndex
        The CAD surface (outward normals).
    signed : bool
        Sign by the side of the closest triangle (only meaningful for a closed mesh); False gives
        the unsigned distance.

    Returns
    -------
    (N,) float array
        Deviation, metres.

    Notes
    -----
    The side is the sign of ``(p - c) . n`` with ``c`` the closest point and ``n`` its triangle's
    outward normal. Where ``c`` lies on an edge both neighbours agree on the side (outside a convex
    edge ``p - c`` points between their normals, inside a concave one between their opposites).
    """
    closest = index.closest(points_cad_m)
    if not signed:
        return closest.distance_m
    side = np.einsum("ij,ij->i", points_cad_m - closest.point_m, index.face_normals[closest.face])
    return np.where(side < 0, -closest.distance_m, closest.distance_m)


def deviation_stats(deviation_m: np.ndarray, tolerance_m: float) -> DeviationStats:
    """:class:`DeviationStats` of ``(N,)`` deviations (metres) against ``tolerance_m``."""
    a = np.abs(deviation_m)
    return DeviationStats(
        n_points=len(deviation_m), rms_m=float(np.sqrt(np.mean(deviation_m ** 2))),
        mean_m=float(np.mean(deviation_m)), p95_abs_m=float(np.percentile(a, 95)), max_abs_m=float(a.max()),
        tolerance_m=float(tolerance_m), within_tolerance=float(np.mean(a <= tolerance_m)))
