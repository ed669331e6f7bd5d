"""The blocked, compact ray caster: same hits whatever the batch shape, misses reported as such."""

from __future__ import annotations

import numpy as np
import trimesh

from scanrig.sim import raycast
from scanrig.sim.raycast import RayCaster, intersect_reference


def _caster_and_rays(n: int, seed: int = 3):
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    box.apply_translation((0.25, 0.0, 0.0))
    caster = RayCaster([sphere.smooth_shaded, box.smooth_shaded])
    origin = np.array([0.05, -0.02, -0.8])
    targets = rng.uniform([-0.15, -0.15, -0.1], [0.35, 0.15, 0.1], size=(n, 3))   # some miss
    dirs = targets - origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return caster, origin, dirs


def test_first_hits_are_the_hits_of_cast_across_blocks(monkeypatch):
    monkeypatch.setattr(raycast, "_BLOCK", 97)          # many blocks, a partial last one
    caster, origin, dirs = _caster_and_rays(1000)
    dirs[[5, 500]] = np.nan                              # rays without a direction miss
    full = caster.cast(np.broadcast_to(origin, dirs.shape), dirs)
    idx, hits = caster.first_hits(origin, dirs)
    assert 0 < idx.size < len(dirs)
    np.testing.assert_array_equal(idx, np.flatnonzero(full.hit))
    assert not full.hit[[5, 500]].any()
    assert np.all(np.isinf(full.t[~full.hit])) and np.all(np.isnan(full.point[~full.hit]))
    for name in ("t", "point", "normal", "shading_normal", "obj"):
        np.testing.assert_array_equal(getattr(hits, name), getattr(full, name)[idx])
    assert set(np.unique(hits.obj)) == {0, 1}


def test_shared_and_per_ray_origins_agree_with_the_reference():
    caster, origin, dirs = _caster_and_rays(300)
    shared = caster.cast(np.broadcast_to(origin, dirs.shape), dirs)
    per_ray = caster.cast(np.repeat(origin[None], len(dirs), axis=0), dirs)
    np.testing.assert_array_equal(shared.obj, per_ray.obj)
    hit = shared.hit
    assert np.abs(shared.point[hit] - per_ray.point[hit]).max() < 1e-15
    t_ref = intersect_reference(caster.triangles, np.repeat(origin[None], len(dirs), axis=0), dirs)
    np.testing.assert_array_equal(np.isfinite(t_ref), hit)
    assert np.abs(shared.t[hit] - t_ref[hit]).max() < 1e-12
    # geometric normals face the incoming rays, shading normals are on their side, unit length
    assert np.all(np.einsum("ij,ij->i", shared.normal[hit], dirs[hit]) < 0)
    assert np.all(np.einsum("ij,ij->i", shared.shading_normal[hit], shared.normal[hit]) > 0.9)
    assert np.abs(np.linalg.norm(shared.shading_normal[hit], axis=1) - 1).max() < 1e-12


def test_occlusion_query_matches_first_hit_distances(monkeypatch):
    monkeypatch.setattr(raycast, "_BLOCK", 64)
    caster, origin, dirs = _caster_and_rays(500, seed=8)
    origins = np.broadcast_to(origin, dirs.shape)
    hits = caster.cast(origins, dirs)
    dist = np.where(hits.hit, hits.t, 1.0)
    assert np.array_equal(caster.occluded(origins, dirs, np.full(len(dirs), 10.0)), hits.hit)
    # stopping well short of the first hit: nothing in the way
    assert not caster.occluded(origins, dirs, 0.5 * dist).any()
