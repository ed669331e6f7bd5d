"""Closest points on the CAD surface: a KD-tree on dense surface samples, then exact triangles.

trimesh's own ``proximity.closest_point`` visits an R-tree per query point and is too slow for a
million points; SciPy's ``cKDTree`` answers a million nearest-sample queries in seconds on two
cores. The nearest samples name candidate triangles, and the exact closest point on each candidate
(``trimesh.triangles.closest_point``, vectorised) gives the distance, so the sampling density sets
only which triangles are tried, not the precision.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

#: Area-weighted random samples of the CAD surface in the KD-tree (plus one per triangle centroid,
#: so that no triangle, however small, is missed).
CAD_SAMPLES = 250_000
#: Nearest samples whose triangles are tried for the exact closest point.
CANDIDATES = 4
#: Query points handled at once by the exact step (bounds memory to ~CHUNK x CANDIDATES triangles).
CHUNK = 100_000
#: Smallest query that is spread over all cores (threads cost more than they save below it).
PARALLEL_MIN = 50_000


@dataclass(frozen=True)
class ClosestPoints:
    """Closest CAD point of each query point.

    Attributes
    ----------
    point_m : (N, 3) float array
        Closest point on the surface, CAD frame, metres.
    face : (N,) int array
        Triangle holding it.
    distance_m : (N,) float array
        Unsigned distance, metres.
    """

    point_m: np.ndarray
    face: np.ndarray
    distance_m: np.ndarray


class CadIndex:
    """Nearest-surface queries on a triangle mesh.

    Parameters
    ----------
    cad : trimesh.Trimesh
        The model, metres. Its face normals are used as given (outward for a closed, consistently
        wound mesh of positive volume; :func:`outward_sign` flips them when it is wound inside out).
    rng : numpy.random.Generator
        Draws the surface samples.
    n_samples : int
        Area-weighted samples (default :data:`CAD_SAMPLES`).
    """

    def __init__(self, cad: trimesh.Trimesh, rng: np.random.Generator, n_samples: int = CAD_SAMPLES):
        self.triangles = np.asarray(cad.triangles, np.float64)              # (F, 3, 3)
        self.face_normals = np.asarray(cad.face_normals, np.float64) * outward_sign(cad)
        self.plane_offset_m = np.einsum("ij,ij->i", self.face_normals, self.triangles[:, 0])
        area = np.asarray(cad.area_faces, np.float64)
        self.area_m2 = float(area.sum())
        face = rng.choice(len(area), n_samples, p=area / area.sum())
        u, v = rng.random((2, n_samples))
        flip = u + v > 1                                                    # fold into the triangle
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        t = self.triangles[face]
        samples = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
        self.n_random = n_samples
        self.sample_m = np.vstack([samples, self.triangles.mean(axis=1)])
        self.sample_face = np.concatenate([face, np.arange(len(area))])
        self.tree = cKDTree(self.sample_m)

    def sparse(self, n_samples: int, rng: np.random.Generator) -> CadIndex:
        """A copy whose tree holds only ``n_samples`` of the random samples.

        A point far from the surface makes a KD-tree visit many leaves (many samples lie at
        nearly the same distance); the coarse search, which starts far off, uses a sparse tree.
        """
        keep = rng.choice(self.n_random, min(n_samples, self.n_random), replace=False)
        other = copy.copy(self)
        other.n_random = len(keep)
        other.sample_m, other.sample_face = self.sample_m[keep], self.sample_face[keep]
        other.tree = cKDTree(other.sample_m)
        return other

    def nearest_planes(self, points_m: np.ndarray, max_distance_m: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Plane of the triangle of each point's nearest sample (for point-to-plane ICP).

        Parameters
        ----------
        points_m : (N, 3) float array
            Query points, CAD frame, metres.
        max_distance_m : float
            Points with no sample this close get a zero normal and an infinite offset (a bounded
            search is much faster for points far from the surface).

        Returns
        -------
        normal : (N, 3) float array
            Unit normal of the plane (zero where no sample is near).
        offset_m : (N,) float array
            ``normal . x = offset_m`` on the plane, metres (inf where no sample is near).
        """
        _, i = self.tree.query(points_m, k=1, distance_upper_bound=max_distance_m, workers=query_workers(len(points_m)))
        found = i < len(self.sample_face)
        face = self.sample_face[np.where(found, i, 0)]
        normal = np.where(found[:, None], self.face_normals[face], 0.0)
        return normal, np.where(found, self.plane_offset_m[face], np.inf)

    @property
    def spacing_m(self) -> float:
        """Typical distance between neighbouring random samples, metres."""
        return float(np.sqrt(self.area_m2 / self.n_random))

    def nearest_sample_distance(self, points_m: np.ndarray) -> np.ndarray:
        """Distance of each point to its nearest surface sample, metres (a quick score)."""
        return self.tree.query(points_m, k=1, workers=query_workers(len(points_m)))[0]

    def closest(self, points_m: np.ndarray) -> ClosestPoints:
        """Exact closest point on the triangles of the :data:`CANDIDATES` nearest samples."""
        n = len(points_m)
        point = np.empty((n, 3))
        face = np.empty(n, np.int64)
        dist = np.empty(n)
        for s in range(0, n, CHUNK):
            p = points_m[s:s + CHUNK]
            _, i = self.tree.query(p, k=CANDIDATES, workers=query_workers(len(p)))
            cand = self.sample_face[i]                                      # (m, K)
            c = trimesh.triangles.closest_point(self.triangles[cand.ravel()],
                                                np.repeat(p, CANDIDATES, axis=0)).reshape(len(p), CANDIDATES, 3)
            d = np.linalg.norm(c - p[:, None], axis=2)
            best = np.argmin(d, axis=1)
            rows = np.arange(len(p))
            point[s:s + CHUNK] = c[rows, best]
            face[s:s + CHUNK] = cand[rows, best]
            dist[s:s + CHUNK] = d[rows, best]
        return ClosestPoints(point, face, dist)


def query_workers(n: int) -> int:
    """cKDTree workers for a query of ``n`` points: all cores for large queries, one otherwise."""
    return -1 if n >= PARALLEL_MIN else 1


def is_closed(cad: trimesh.Trimesh) -> bool:
    """The mesh bounds a volume: watertight and consistently wound, so inside/outside is defined."""
    return bool(cad.is_watertight and cad.is_winding_consistent)


def outward_sign(cad: trimesh.Trimesh) -> float:
    """-1 when a closed mesh is wound inside out (negative volume), so its normals must flip; else 1."""
    return -1.0 if is_closed(cad) and cad.volume < 0 else 1.0
