"""Checking a prediction against a simulated scan of the same rig.

The points a rig covers are projected into the cameras that use them, the pixels get Gaussian
noise of the predicted per-axis sigma (detection and speckle), and the pipeline's triangulation
(:func:`scanrig.geometry.triangulation.triangulate`, Gauss–Newton refined) recovers them. If the
prediction is right, the errors whitened by the predicted covariance are standard normal: their
spread (standard deviation over all points and axes) is 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.geometry.camera import Camera
from scanrig.geometry.triangulation import triangulate
from scanrig.geometry.uncertainty import inv_sym3

from . import accuracy
from .analysis import RigAnalysis
from .spec import DesignSpec


@dataclass(frozen=True)
class PredictionCheck:
    """Simulated-scan errors against the prediction.

    Attributes
    ----------
    normalised_spread : float
        Standard deviation of the whitened errors ``L^-1 (p_hat - p)`` (``cov = L L^T``) over all
        points and axes; 1 when the predicted covariances are right.
    sigma_ratio : float
        RMS 3-D error over the RMS of ``sqrt(trace(cov))``; 1 when the predicted sizes are right.
    n_points : int
        Points triangulated.
    """

    normalised_spread: float
    sigma_ratio: float
    n_points: int


def check_prediction(cameras: list[Camera], analysis: RigAnalysis, spec: DesignSpec,
                     rng: np.random.Generator, n_points: int = 2000) -> PredictionCheck:
    """Simulate noisy detections of covered points and compare the errors with the prediction.

    Parameters
    ----------
    cameras : list of Camera
        The rig that ``analysis`` describes.
    analysis : RigAnalysis
    spec : DesignSpec
        Complete spec (pixel noise from ``laser`` and ``camera``); calibration error is not
        simulated, so its terms must be zero for the check to be meaningful.
    rng : numpy.random.Generator
        Chooses the points and draws the noise.
    n_points : int
        Covered elements to simulate (fewer if fewer are covered).

    Returns
    -------
    PredictionCheck
    """
    covered = np.flatnonzero(analysis.n_views >= spec.target.min_views)
    pick = rng.choice(covered, size=min(n_points, covered.size), replace=False)
    points = analysis.elements.points[pick]
    used = analysis.used[:, pick]
    sigma_px = accuracy.pixel_sigma_px(spec.camera, spec.laser)
    q_obs = np.full((len(cameras), pick.size, 2), np.nan)
    for i, cam in enumerate(cameras):
        q_obs[i, used[i]] = cam.project(points[used[i]]) + rng.normal(0.0, sigma_px, (int(used[i].sum()), 2))
    p_hat, _ = triangulate(cameras, q_obs, sigma_px=sigma_px, refine=True)
    info = np.zeros((pick.size, 3, 3))
    for i, cam in enumerate(cameras):
        info[used[i]] += accuracy.information(cam, points[used[i]], sigma_px, spec.calibration)[0]
    cov, _ = inv_sym3(info)
    ok = np.all(np.isfinite(p_hat), axis=1) & np.all(np.isfinite(cov), axis=(1, 2))
    error = p_hat[ok] - points[ok]
    L = np.linalg.cholesky(cov[ok])
    whitened = np.linalg.solve(L, error[:, :, None])[:, :, 0]
    rms_error = np.sqrt(np.mean(np.sum(error**2, axis=1)))
    rms_predicted = np.sqrt(np.mean(np.trace(cov[ok], axis1=1, axis2=2)))
    return PredictionCheck(float(np.std(whitened)), float(rms_error / rms_predicted), int(ok.sum()))

