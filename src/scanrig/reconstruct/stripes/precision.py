"""The precision cut of stripe mode: which points are too imprecise to keep."""

from __future__ import annotations

import numpy as np

from scanrig.reconstruct.light_plane import MIN_PLANE_POINTS
from scanrig.reconstruct.points import PointCloud

#: Points whose sigma exceeds this multiple of the median sigma of the session's three-view points
#: (the rig's typical self-checked precision) are left out: with honest covariances they are not
#: wrong, but they are too imprecise to help a surface that the other points pin down better.
MAX_SIGMA_RATIO = 1.5


def default_max_sigma(cloud: PointCloud) -> float:
    """Largest sigma kept (metres): :data:`MAX_SIGMA_RATIO` times the median three-view sigma.

    With fewer than ``MIN_PLANE_POINTS`` three-view points the two-view points are the
    reference; without any, every point is kept (``inf``).
    """
    reference = cloud.sigma[cloud.n_views >= 3]
    if reference.size < MIN_PLANE_POINTS:
        reference = cloud.sigma[cloud.n_views >= 2]
    return MAX_SIGMA_RATIO * float(np.median(reference)) if reference.size else np.inf
