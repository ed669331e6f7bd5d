"""Robust ICP when points leave the search bound: no NaN weights, no singular solve."""

import numpy as np

from scanrig.inspect.closest import CadIndex
from scanrig.inspect.icp import robust_icp, trimmed_weights

from . import synth


def test_trimmed_weights_never_keep_an_infinite_residual():
    keep = trimmed_weights(0.6)
    np.testing.assert_array_equal(keep(np.array([np.inf, -np.inf, 1e-4, -2e-4, 3e-4])), [0, 0, 1, 1, 1])
    np.testing.assert_array_equal(keep(np.full(4, np.inf)), np.zeros(4))
    residual = np.random.default_rng(0).normal(size=100)
    np.testing.assert_array_equal(keep(residual), np.abs(residual) <= np.quantile(np.abs(residual), 0.6))


def test_icp_with_no_point_to_fit_stops_where_it_is():
    """A trial start from which every point falls outside the search bound used to solve a zero
    system (numpy's LinAlgError); it now ends there, with an infinite RMS."""
    mesh = synth.bracket_mesh()
    index = CadIndex(mesh, np.random.default_rng(0))
    points = mesh.sample(200, seed=np.random.default_rng(1))
    start = np.eye(4)
    result = robust_icp(points, index, start, weight_fn=np.zeros_like, size_m=0.1)
    np.testing.assert_array_equal(result.cad_from_cloud, start)
    assert result.residual_rms_m == np.inf and result.inlier_fraction == 0.0
