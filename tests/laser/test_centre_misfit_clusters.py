"""The cluster-robust centre variance of :func:`scanrig.laser.fit.centre_misfit`.

Stripe profiles whose noise is drawn once per pair of neighbouring pixels (perfectly correlated
pairs, as a subsampled chroma sample or a demosaiced neighbour makes them) scatter with 1.74 times
the variance stated for independent pixels; with the pairs given as clusters, 1.18 times (the
window's centre is carried by about four pairs, so each window's own estimate is rough).
"""

import numpy as np

from scanrig.laser.fit import MIN_PEAK_DN, MIN_WIDTH_PX, centre_misfit, fit_batch, minor_model_1d

from .synth import integrated

HALF = 10
X = np.arange(-HALF, HALF + 1.0)
NOISE = 2.0  # DN
#: Pixels 2k and 2k + 1 of a window share one noise draw.
PAIRS = (np.arange(X.size) // 2)[:, None]


def _variance_ratio(clusters):
    """Mean squared centre error over the mean stated variance of 2000 paired-noise stripe fits,
    with ``clusters`` given to ``centre_misfit`` (None: every pixel independent)."""
    rng = np.random.default_rng(5)
    n = 2000
    centre, width, peak = rng.uniform(-0.5, 0.5, n), rng.uniform(1.0, 2.0, n), rng.uniform(80, 200, n)
    noise = rng.normal(0, NOISE, (PAIRS.max() + 1, n))[PAIRS[:, 0]]  # (W, n), equal in pairs
    y = (10.0 + peak * integrated(X[:, None], centre, width) + noise) / NOISE  # whitened
    p0 = np.column_stack([peak / NOISE, np.zeros(n), np.full(n, 1.5), np.full(n, 10.0 / NOISE)])
    lower = np.array([MIN_PEAK_DN / NOISE, -HALF, MIN_WIDTH_PX, -np.inf])
    upper = np.array([np.inf, HALF, 4.0, np.inf])
    res = fit_batch(minor_model_1d(X), y, np.ones(y.shape, bool), p0, lower, upper, 30, minor=True,
                    noise_var=np.ones(n))
    factor = centre_misfit(res.jac.transpose(2, 1, 0), res.info_inv, res.residuals.T, np.ones(y.shape), res.dof,
                           (1,), None if clusters is None else np.broadcast_to(clusters, y.shape))
    return np.mean((res.params[:, 1] - centre) ** 2) / np.mean(res.info_inv[:, 1, 1] * factor)


def test_correlated_pairs_are_understated_as_independent_pixels():
    # the pairs' χ² is that of independent noise: the misfit test does not see them
    assert _variance_ratio(None) > 1.5


def test_clusters_make_the_sigma_of_correlated_pairs_honest():
    assert 0.85 <= _variance_ratio(PAIRS) <= 1.25
