"""Robust ICP: several starts at once as each alone, and points leaving the search bound (no NaN
weights, no singular solve)."""

import numpy as np

from scanrig.inspect.closest import CadIndex
from scanrig.inspect.icp import icp_trials, robust_icp, trimmed_weights, tukey_weights

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


def test_starts_run_together_end_where_each_alone_ends():
    """The coarse search's batch of starts: every start's own iterations and stops
    (starts near and far, and one so far that no point is fitted: residuals over 1 m get no weight)."""
    mesh = synth.bracket_mesh()
    index = CadIndex(mesh, np.random.default_rng(0)).sparse(5000, np.random.default_rng(1))
    points = mesh.sample(400, seed=np.random.default_rng(2))
    rng = np.random.default_rng(3)
    starts = np.stack([synth.random_motion(rng, max_angle_deg=a, max_shift_m=0.01) for a in (1, 20, 60, 120, 180)]
                      + [np.eye(4)])
    starts[-1, :3, 3] = 10.0  # every point about 17 m from the part
    trimmed = trimmed_weights(0.6)

    def weights(r):
        return trimmed(np.where(np.abs(r) > 1.0, np.inf, r))

    together = icp_trials(points, index, starts, weight_fn=weights, size_m=0.1, max_iterations=25)
    for k, start in enumerate(starts):
        alone = robust_icp(points, index, start, weight_fn=weights, size_m=0.1, max_iterations=25)
        np.testing.assert_allclose(together.cad_from_cloud[k], alone.cad_from_cloud, rtol=0, atol=1e-12)
        assert together.iterations[k] == alone.iterations
    assert together.iterations[-1] == 1 and np.array_equal(together.cad_from_cloud[-1], starts[-1])
    assert len(set(together.iterations[:-1])) > 1  # the others stopped at different iterations


def test_tukey_weights_scale_each_row_by_its_own_residuals():
    rng = np.random.default_rng(4)
    rows = np.stack([rng.normal(scale=s, size=200) for s in (1e-5, 1e-3)])
    np.testing.assert_array_equal(tukey_weights(rows), np.stack([tukey_weights(row) for row in rows]))
