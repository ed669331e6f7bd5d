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


def test_normals_of_laser_stripes_are_the_surface_normal():
    # 15 lines 14 mm apart, 1.7 mm between points along each: a point's 16 nearest neighbours
    # all lie on its own line, whose covariance leaves the normal free to turn about it
    # (the median |n_z| was 0.09 on such stripes, and the cloud fell into 64 charts)
    y = np.linspace(-0.1, 0.1, 120)
    x = np.linspace(-0.1, 0.1, 15)[:, None] + 0.002 * np.sin(10 * y)
    points = np.column_stack([x.ravel(), np.broadcast_to(y, x.shape).ravel(), 0.1 * x.ravel()])
    points[:, 2] += np.random.default_rng(0).normal(0, 1e-5, len(points))
    normal = np.array([-0.1, 0.0, 1.0]) / np.hypot(0.1, 1.0)
    assert np.min(np.abs(estimate_normals(points) @ normal)) >= np.cos(np.deg2rad(2.0))
