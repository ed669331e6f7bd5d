"""Chart splitting of a closed object."""

import numpy as np

from scanrig.surface.charts import blend_weights, estimate_normals, split_charts


def test_sphere_is_split_into_height_field_charts_that_partition_it():
    rng = np.random.default_rng(11)
    v = rng.normal(size=(4000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    points = 0.05 * v + rng.normal(0, 1e-4, v.shape)
    normals = estimate_normals(points)
    # normals of a 0.05 m sphere with 1e-4 m noise: within a few degrees of the radius
    assert np.median(np.abs(np.sum(normals * v, axis=1))) > np.cos(np.deg2rad(5))
    charts = split_charts(points, normals, max_points=1000, q=0.1)
    assert len(charts) >= 4
    owned = np.concatenate([c.core for c in charts])
    np.testing.assert_array_equal(np.sort(owned), np.arange(len(points)))  # a partition
    for c in charts:
        assert np.all(np.isin(c.core, c.members))
        assert np.all(blend_weights(c, points[c.core]) > 0)
        # a height field: no member's true normal turns more than 60 deg (+ slack for the
        # noisy normal estimate) from the chart normal, and no member lies on the far side
        assert np.all(np.abs(v[c.members] @ c.rotation[2]) > np.cos(np.deg2rad(65)))
        assert np.all(v[c.members] @ c.rotation[2] * np.sign(v[c.core] @ c.rotation[2]).mean() > 0)
        np.testing.assert_allclose(c.rotation @ c.rotation.T, np.eye(3), atol=1e-12)


def test_a_far_gross_error_does_not_widen_a_chart():
    # a flat patch with one point 0.5 m above it: the reach is the core's box in the chart
    # plane, so the chart's members stay its core plus the overlap (a 3D ball around the
    # origin took its radius from the gross error and held the whole neighbourhood)
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.5, 0.5, (4000, 2))
    points = np.column_stack([xy, rng.normal(0, 1e-3, len(xy))])
    points[0] = [0.0, 0.0, 0.5]
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    charts = split_charts(points, normals, max_points=1000, q=0.1)
    for c in charts:
        assert c.radius <= np.sqrt(0.5) + 1e-9
        assert len(c.members) <= 1.6 * len(c.core)  # (1 + 0.25)^2 = 1.56 for a square box
