"""Shared synthetic data for the surface tests."""

import numpy as np
import pytest
import torch

from scanrig.surface.fit_settings import FitSettings

SIGMA = 0.01  # inlier noise, metres
# Small network and short schedule so a fit takes seconds; the accuracy checks below are
# loose enough for it (stated per test) and still fail for a non-robust fit.
FAST = FitSettings(hidden=12, depth=2, epochs=180, update_every=30)


@pytest.fixture(autouse=True)
def _one_torch_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the test machine is shared; avoid thread oversubscription
    yield
    torch.set_num_threads(threads)


def tilted_plane_with_outliers(rng, n_side=32, eps=0.2):
    """Grid over [-1, 1]^2 on z = 0.3x - 0.2y + 0.1, noise SIGMA along z, one-sided outliers.

    Returns points (N, 3), true heights (N,), outlier mask (N,), outlier offsets (N,).
    """
    g = np.linspace(-1, 1, n_side)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    truth = 0.3 * x - 0.2 * y + 0.1
    z = truth + rng.normal(0, SIGMA, x.size)
    bad = rng.random(x.size) < eps
    offset = np.where(bad, rng.uniform(5 * SIGMA, 0.3, x.size), 0.0)
    return np.column_stack([x, y, z + offset]), truth, bad, offset
