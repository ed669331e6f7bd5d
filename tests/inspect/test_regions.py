"""worst_regions: out-of-tolerance points joined by proximity, isolated points left out."""

import numpy as np
import trimesh

from scanrig.inspect.closest import CadIndex
from scanrig.inspect.regions import MIN_REGION_POINTS, worst_regions


def _plane_index():
    """The z = 0 face of a thin slab under the test plane (outward normal +z there)."""
    slab = trimesh.creation.box(extents=(0.06, 0.06, 0.002))
    slab.apply_translation((0.025, 0.025, -0.001))
    return CadIndex(slab, np.random.default_rng(0), n_samples=20_000)


def test_two_patches_are_two_regions_worst_first_and_stray_points_are_not():
    rng = np.random.default_rng(0)
    # a 50 x 50 mm plane sampled every 0.5 mm; a bump patch and a dent patch; 3 stray out-of-tolerance points
    u = np.arange(0.0, 0.05, 5e-4)
    x, y = np.meshgrid(u, u)
    p = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    deviation = rng.normal(scale=1e-5, size=len(p))
    bump = np.linalg.norm(p[:, :2] - [0.01, 0.01], axis=1) < 2e-3
    dent = np.linalg.norm(p[:, :2] - [0.04, 0.03], axis=1) < 3e-3
    deviation[bump], deviation[dent] = 3e-4, -5e-4
    stray = rng.choice(np.flatnonzero(~bump & ~dent), MIN_REGION_POINTS - 2, replace=False)
    deviation[stray] = 1e-3
    regions = worst_regions(p, deviation, 1e-4, _plane_index(), rng)
    assert len(regions) == 2
    dent_region, bump_region = regions                         # largest |peak| first
    assert dent_region.peak_m == -5e-4 and dent_region.n_points == int(dent.sum())
    assert bump_region.peak_m == 3e-4 and bump_region.n_points == int(bump.sum())
    # centroids of symmetric grid patches lie on their centres to within a grid step
    np.testing.assert_allclose(dent_region.centroid_m, [0.04, 0.03, 0.0], atol=5e-4)
    np.testing.assert_allclose(bump_region.centroid_m, [0.01, 0.01, 0.0], atol=5e-4)
    assert dent_region.facing == bump_region.facing == "+z"


def test_no_region_when_everything_is_within_tolerance():
    p = np.random.default_rng(1).random((100, 3))
    assert worst_regions(p, np.zeros(100), 1e-4, _plane_index(), np.random.default_rng(1)) == ()
