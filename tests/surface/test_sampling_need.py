"""Sampling-need map on a paraboloid with a hole."""

import numpy as np
import pytest

from scanrig.surface import filter_points
from scanrig.surface.sampling_need import _max_principal_curvature, _mesh_spacing, sampling_need


C = 0.4  # z = C (x^2 + y^2) / 2: principal curvatures C / W^(1/2) and C / W^(3/2)
NOISE = 1e-3
HOLE = (np.array([0.4, -0.3]), 0.25)


@pytest.fixture(scope="module")
def need_map():
    # default network: the FAST one's second derivatives are too rough for the curvature test
    rng = np.random.default_rng(2026)
    xy = rng.uniform(-1, 1, (1500, 2))
    xy = xy[np.linalg.norm(xy - HOLE[0], axis=1) > HOLE[1]]
    z = 0.5 * C * (xy**2).sum(axis=1) + rng.normal(0, NOISE, len(xy))
    result = filter_points(np.column_stack([xy, z]), rng=np.random.default_rng(3))
    return sampling_need(result, tolerance=1e-3)


def test_curvature_of_the_fit_matches_the_surface(need_map):
    p = need_map.positions
    interior = np.all(np.abs(p[:, :2]) < 0.7, axis=1) & (np.linalg.norm(p[:, :2] - HOLE[0], axis=1) > HOLE[1])
    grad = C * p[interior, :2]
    hess = np.broadcast_to(C * np.eye(2), (interior.sum(), 2, 2))
    kappa_true = _max_principal_curvature(grad, hess)
    kappa_fit = 8e-3 / need_map.h_required[interior] ** 2
    # second derivatives of a fit to 1e-3 m noise over a 2 m patch: a 20 % median error is ~3x
    # what the FAST network reaches
    assert np.median(np.abs(kappa_fit / kappa_true - 1)) < 0.2


def test_hole_needs_samples(need_map):
    p = need_map.positions
    centre, radius = HOLE
    deep = np.linalg.norm(p[:, :2] - centre, axis=1) < 0.3 * radius
    assert deep.sum() > 5
    # the mesh's triangles over the hole span it: their chords at a node near its centre are
    # about the hole's diameter 2R (0.49-0.51 m measured), against ~2.4 spacings elsewhere
    # (~375 inliers per m^2: spacing 0.052 m, median chord 0.12-0.13 m measured)
    assert np.all(need_map.h_actual[deep] >= 1.4 * radius)
    assert np.median(need_map.h_actual[~deep]) < 0.6 * radius
    # elsewhere ~350 inliers per m^2 give r_8 ~ 0.085 m: density is > 2x lower in the hole
    assert np.median(need_map.density_need[deep]) > 2 * np.median(need_map.density_need[~deep])
    np.testing.assert_allclose(np.linalg.norm(need_map.normals, axis=1), 1.0, atol=1e-9)


def test_mesh_spacing_is_the_chord_of_the_circumcircle_through_the_node():
    # a square grid of spacing s: right triangles, circumcentre at the hypotenuse's midpoint,
    # R = s / sqrt(2); chord 0 at a sample, 2R = s sqrt(2) at a square's centre
    s = 0.01
    g = np.arange(5) * s
    samples = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    nodes = np.array([[s, s], [1.5 * s, 2.5 * s], [-s, 0.0]])  # a sample, a centre, outside
    chord = _mesh_spacing(samples, nodes)
    np.testing.assert_allclose(chord, [0.0, s * np.sqrt(2), s * np.sqrt(2)], atol=1e-9)  # sqrt of rounding
    assert np.all(np.isinf(_mesh_spacing(np.column_stack([g, g]), nodes)))  # collinear: no mesh
