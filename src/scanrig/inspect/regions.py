"""The worst regions: out-of-tolerance points clustered by proximity, each named by its position."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from scanrig.inspect.closest import CadIndex, query_workers

#: Out-of-tolerance points closer than this many cloud spacings belong to one region.
LINK_SPACINGS = 3.0
#: Smallest region reported (fewer points are isolated outliers, not a region).
MIN_REGION_POINTS = 5
#: Regions reported, worst (largest |peak|) first.
MAX_REGIONS = 10
#: A normal component at least this large names its axis in :attr:`Region.facing` (cos 60 deg).
FACING_COMPONENT = 0.5
#: Points used to estimate the cloud's spacing.
SPACING_SAMPLE = 200_000


@dataclass(frozen=True)
class Region:
    """A connected patch of out-of-tolerance points.

    Attributes
    ----------
    centroid_m : (3,) float array
        Mean position, CAD frame, metres.
    peak_m : float
        Signed deviation of largest magnitude in the region, metres (> 0: material added, a bump).
    mean_m : float
        Mean signed deviation, metres.
    n_points : int
        Points in the region.
    radius_m : float
        Largest distance of a region point from the centroid, metres.
    normal : (3,) float array
        Outward normal of the CAD surface nearest the centroid (which side of the part it is on).
    """

    centroid_m: np.ndarray
    peak_m: float
    mean_m: float
    n_points: int
    radius_m: float
    normal: np.ndarray

    @property
    def facing(self) -> str:
        """The side of the part in words: the CAD axes the normal leans along, e.g. ``+z`` or ``+x -y``."""
        return " ".join(f"{'+' if c > 0 else '-'}{'xyz'[k]}" for k, c in enumerate(self.normal)
                        if abs(c) >= FACING_COMPONENT)

    def as_dict(self) -> dict:
        return {"centroid_m": self.centroid_m.tolist(), "peak_m": self.peak_m, "mean_m": self.mean_m,
                "n_points": self.n_points, "radius_m": self.radius_m, "normal": self.normal.tolist(),
                "facing": self.facing}


def cloud_spacing_m(points_m: np.ndarray, rng: np.random.Generator) -> float:
    """Median nearest-neighbour spacing of a surface cloud, from a subsample scaled by sqrt(n/N)."""
    n = min(len(points_m), SPACING_SAMPLE)
    sample = points_m[rng.choice(len(points_m), n, replace=False)] if n < len(points_m) else points_m
    d, _ = cKDTree(sample).query(sample, k=2, workers=query_workers(n))
    return float(np.median(d[:, 1]) * np.sqrt(n / len(points_m)))


def worst_regions(points_cad_m: np.ndarray, deviation_m: np.ndarray, tolerance_m: float,
                  index: CadIndex, rng: np.random.Generator) -> tuple[Region, ...]:
    """Cluster the points with ``|deviation| > tolerance_m`` and return the worst regions.

    Parameters
    ----------
    points_cad_m : (N, 3) float array
        Points, CAD frame, metres.
    deviation_m : (N,) float array
        Their signed deviations, metres.
    tolerance_m : float
        The tolerance, metres.
    index : CadIndex
        The CAD surface (gives each region's side).
    rng : numpy.random.Generator
        Draws the spacing subsample.

    Returns
    -------
    tuple of Region
        At most :data:`MAX_REGIONS`, of at least :data:`MIN_REGION_POINTS` points each, largest
        ``|peak_m|`` first.
    """
    out = np.flatnonzero(np.abs(deviation_m) > tolerance_m)
    if len(out) < MIN_REGION_POINTS or len(points_cad_m) < 2:
        return ()
    p, dev = points_cad_m[out], deviation_m[out]
    pairs = cKDTree(p).query_pairs(LINK_SPACINGS * cloud_spacing_m(points_cad_m, rng), output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(p), len(p)))
    _, label = connected_components(graph, directed=False)
    count = np.bincount(label)
    centroid = np.stack([np.bincount(label, p[:, k]) for k in range(3)], axis=1) / count[:, None]
    mean = np.bincount(label, dev) / count
    order = np.lexsort((np.abs(dev), label))                 # by label, largest |dev| last in each
    last = np.r_[np.flatnonzero(np.diff(label[order])), len(order) - 1]
    peak = dev[order[last]]
    radius = np.zeros(len(count))
    np.maximum.at(radius, label, np.linalg.norm(p - centroid[label], axis=1))
    keep = np.flatnonzero(count >= MIN_REGION_POINTS)
    keep = keep[np.argsort(-np.abs(peak[keep]), kind="stable")][:MAX_REGIONS]
    normal = index.face_normals[index.closest(centroid[keep]).face] if len(keep) else np.zeros((0, 3))
    return tuple(Region(centroid[k], float(peak[k]), float(mean[k]), int(count[k]), float(radius[k]), n)
                 for k, n in zip(keep, normal))
