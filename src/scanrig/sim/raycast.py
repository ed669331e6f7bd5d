"""Ray casting against the scene's triangles with Embree (through ``embreex``), refined in float64.

Embree works in float32; each hit is re-intersected in float64 with the plane of the triangle
Embree found, so hit points are exact to float64 round-off (the float32 search only picks the
triangle). A pure-numpy reference (:func:`intersect_reference`) exists for tests only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

#: Rays per Embree call; bounds the float32 copies of huge batches.
_CHUNK = 1 << 21


@dataclass(frozen=True)
class Hits:
    """First intersections of a batch of rays (world frame, metres).

    Attributes
    ----------
    t : ndarray of shape (N,)
        Distance along the unit ray to the hit; ``inf`` on a miss.
    point : ndarray of shape (N, 3)
        Hit points; NaN on a miss.
    normal : ndarray of shape (N, 3)
        Unit geometric normal of the hit triangle, turned to face the incoming ray.
    shading_normal : ndarray of shape (N, 3)
        Unit interpolated normal (smooth across curved tessellations, sharp at real edges), on
        the same side as ``normal``.
    obj : ndarray of shape (N,), int
        Index of the scene object hit; -1 on a miss.
    """

    t: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    shading_normal: np.ndarray
    obj: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """Boolean mask of rays that hit something."""
        return self.obj >= 0


class RayCaster:
    """Embree scene over several meshes, answering first-hit queries.

    Parameters
    ----------
    meshes : list of trimesh.Trimesh
        Meshes in world coordinates; hits report the list index as ``obj``. Each should have
        been split at sharp edges (``mesh.smooth_shaded``) so vertex normals shade correctly.
    """

    def __init__(self, meshes: list[trimesh.Trimesh]):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.triangles = np.concatenate([m.triangles for m in meshes]).astype(np.float64)   # (F, 3, 3)
        normals = np.cross(self.triangles[:, 1] - self.triangles[:, 0], self.triangles[:, 2] - self.triangles[:, 0])
        self.face_normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
        self.corner_normals = np.concatenate([m.vertex_normals[m.faces] for m in meshes])  # (F, 3, 3)
        self.face_object = np.repeat(np.arange(len(meshes)), [len(m.faces) for m in meshes])
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self._scene, self.triangles.astype(np.float32))

    def cast(self, origins: np.ndarray, dirs: np.ndarray, max_dist: np.ndarray | None = None) -> Hits:
        """First hits of rays.

        Parameters
        ----------
        origins, dirs : ndarray of shape (N, 3)
            Ray origins and unit directions, world frame. Rays with NaN directions miss.
        max_dist : ndarray of shape (N,), optional
            Hits farther than this are ignored (shadow rays).

        Returns
        -------
        Hits
        """
        origins = np.asarray(origins, dtype=np.float64)
        dirs = np.asarray(dirs, dtype=np.float64)
        n = len(origins)
        prim = np.full(n, -1, dtype=np.int64)
        bary = np.zeros((n, 2), dtype=np.float32)
        bad = ~np.all(np.isfinite(dirs), axis=1)
        safe_dirs = np.where(bad[:, None], [0.0, 0.0, 1.0], dirs)
        for s in range(0, n, _CHUNK):
            e = min(n, s + _CHUNK)
            dists = None if max_dist is None else np.asarray(max_dist[s:e], dtype=np.float32)
            res = self._scene.run(origins[s:e].astype(np.float32), safe_dirs[s:e].astype(np.float32),
                                  dists=dists, output=1)
            prim[s:e] = res["primID"]
            bary[s:e, 0], bary[s:e, 1] = res["u"], res["v"]
        prim[bad] = -1
        return self._refine(origins, dirs, prim, bary)

    def occluded(self, origins: np.ndarray, dirs: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """True where something lies on the ray within ``dist`` (shadow test), shape (N,).

        Only Embree's any-triangle answer is needed, so no float64 refinement is done.
        """
        n = len(origins)
        blocked = np.zeros(n, dtype=bool)
        dirs32 = np.asarray(dirs, dtype=np.float32)
        dist32 = np.maximum(np.asarray(dist, dtype=np.float32), 0.0)
        for s in range(0, n, _CHUNK):
            e = min(n, s + _CHUNK)
            prim = self._scene.run(np.asarray(origins[s:e], dtype=np.float32), dirs32[s:e], dists=dist32[s:e])
            blocked[s:e] = prim >= 0
        return blocked

    def _refine(self, origins, dirs, prim, bary) -> Hits:
        n = len(origins)
        t = np.full(n, np.inf)
        point = np.full((n, 3), np.nan)
        normal = np.full((n, 3), np.nan)
        shading = np.full((n, 3), np.nan)
        obj = np.full(n, -1, dtype=np.int64)
        ok = prim >= 0
        if np.any(ok):
            f = prim[ok]
            o, d = origins[ok], dirs[ok]
            nf = self.face_normals[f]
            denom = np.einsum("ij,ij->i", nf, d)
            t_ok = np.einsum("ij,ij->i", nf, self.triangles[f, 0] - o) / denom
            p = o + t_ok[:, None] * d
            # Embree's float32 barycentrics are ample for interpolating normals
            u, v = bary[ok, 0:1].astype(np.float64), bary[ok, 1:2].astype(np.float64)
            cn = self.corner_normals[f]
            ns = (1.0 - u - v) * cn[:, 0] + u * cn[:, 1] + v * cn[:, 2]
            ns /= np.linalg.norm(ns, axis=1, keepdims=True)
            flip = np.where(denom > 0, -1.0, 1.0)[:, None]
            t[ok], point[ok], normal[ok] = t_ok, p, nf * flip
            shading[ok] = ns * flip
            obj[ok] = self.face_object[f]
        return Hits(t, point, normal, shading, obj)


def intersect_reference(triangles: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Slow pure-numpy first-hit distances (Möller–Trumbore over all pairs), for tests only.

    Parameters
    ----------
    triangles : ndarray of shape (F, 3, 3)
    origins, dirs : ndarray of shape (N, 3)

    Returns
    -------
    ndarray of shape (N,)
        Distance to the nearest hit, ``inf`` on a miss.
    """
    e1 = triangles[None, :, 1] - triangles[None, :, 0]
    e2 = triangles[None, :, 2] - triangles[None, :, 0]
    d = dirs[:, None, :]
    pvec = np.cross(d, e2)
    det = (e1 * pvec).sum(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        tvec = origins[:, None, :] - triangles[None, :, 0]
        u = (tvec * pvec).sum(-1) * inv
        qvec = np.cross(tvec, e1)
        v = (d * qvec).sum(-1) * inv
        t = (e2 * qvec).sum(-1) * inv
    ok = (np.abs(det) > 1e-15) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return np.where(ok, t, np.inf).min(axis=1)
