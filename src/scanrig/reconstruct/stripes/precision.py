"""The precision cut: points whose predicted sigma exceeds the accuracy target (stripe default).

The rule follows from the noise model. A point's ``sigma`` is the standard deviation along the
largest axis of its covariance, so with honest covariances its error along *any* direction — in
particular along the surface normal, which a distance to the surface measures — has a standard
deviation of at most ``sigma``. Keeping only the points with ``sigma <= σ_max`` therefore bounds
the expected RMS distance of the kept cloud to the true surface by ``σ_max``, whatever the mix of
three-view, two-view and single-view points and whatever the session; a cut relative to a
typical sigma of the session (the former rule: 1.5 × the median three-view sigma) bounds nothing
in millimetres and moves with the calibration's quality. So ``σ_max`` is the accuracy the scan
must reach: :data:`TARGET_SIGMA_M` unless the user sets it (``scanrig reconstruct
--max-sigma-mm``). The bound is conservative by the ratio of the normal component to the largest
axis (0.6-0.85 on the simulated sessions).

A rig that cannot reach the target — a long working distance, a poor calibration — keeps few
points; its summary says how many were left out (``points_imprecise``, ``max_sigma_mm``), and its
user sets the accuracy it needs instead. The cut bounds the noise, not gross errors: those are
the consistency tests' task (no point of the simulated sessions is 1 mm off even without a cut).
"""

from __future__ import annotations

from scanrig.reconstruct.points import PointCloud

#: Accuracy target of a stripe point, metres: 0.1 mm, the RMS distance to the surface that issue 6
#: asks of stripe mode, imposed on each point's largest-axis 1-sigma.
TARGET_SIGMA_M = 1e-4


def split_by_precision(cloud: PointCloud, max_sigma_m: float) -> tuple[PointCloud, PointCloud]:
    """The points whose sigma is at most ``max_sigma_m`` (metres), and the others.

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
