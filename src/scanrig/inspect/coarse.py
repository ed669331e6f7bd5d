"""Global coarse alignment of a scan to its CAD model, with no hand placing.

Two methods give candidates:

``features``
    Open3D's FPFH descriptors on voxel-downsampled copies of the cloud and of the CAD surface,
    matched by RANSAC (Rusinkiewicz-style 3-point hypotheses checked by edge length and distance).
    It is pose-independent and copes with partial scans and outliers. Open3D is an optional
    extra (``pip install "scanrig[open3d]"``), so it is used only when importable.
``multistart``
    Our own, for installations without Open3D and for parts whose features RANSAC cannot match
    (planar faces give FPFH little to tell apart): trimmed point-to-plane ICP on a few hundred
    points from many starting rotations (the identity, the 24 ways of matching the principal
    axes of cloud and CAD, random rotations), the cloud's median moved onto the CAD's centre;
    the starts whose closest 60 % of points lie nearest the surface go on. Trimming, not a
    robust scale, lets a partial scan slide over the part.

Every candidate (the feature match and the best multi-start trials) is refined by trimmed, then
robust, ICP on a few thousand points, and the one that brings the most points close to the surface
wins: a wrong match that lays one face onto another leaves the rest of the cloud off the part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from scanrig.errors import InputError
from scanrig.inspect.closest import CadIndex
from scanrig.inspect.icp import icp_trials, robust_icp, trimmed_weights

#: The coarse search sees at most this many points of the cloud (a random subsample).
COARSE_POINTS = 40_000
#: Voxels across the CAD's bounding-box diagonal for the feature stage.
VOXELS_ACROSS = 50
#: FPFH normal and feature radii, in voxels.
NORMAL_RADIUS_VOXELS = 2.0
FEATURE_RADIUS_VOXELS = 5.0
#: RANSAC: inlier distance in voxels, iterations and confidence.
RANSAC_DISTANCE_VOXELS = 1.5
RANSAC_ITERATIONS = 100_000
RANSAC_CONFIDENCE = 0.999
#: Points used by each multi-start trial and by the final check of the coarse methods.
TRIAL_POINTS = 400
CHECK_POINTS = 2000
#: CAD samples in the multi-start trials' KD-tree (a sparse tree answers far-off queries fast).
TRIAL_SAMPLES = 5000
#: Random starting rotations added to the 24 principal-axis matches. Few starts converge on a
#: scan of one side (1 of 65 on a benchmark bracket): with 40, the multi-start search alone missed
#: the pose on 2 of 12 seeds of the inspection benchmark's bracket; with 100, on none of them.
RANDOM_STARTS = 100
#: Trimmed ICP keeps this fraction of the points (tolerates 30 % outliers and partial views).
TRIM_KEEP = 0.6
#: Iterations of a multi-start trial.
TRIAL_ITERATIONS = 25
#: Starts refined on CHECK_POINTS after the trials.
FINALISTS = 2
#: A point overlaps the CAD when it lies within this fraction of the part's size of the surface
#: (0.15 mm on a 75 mm part: far above scan noise, far below the gap of a wrong match).
OVERLAP_FRACTION = 0.002
METHODS = ("auto", "features", "multistart")


@dataclass(frozen=True)
class CoarseResult:
    """A coarse ``cad_from_cloud`` ((4, 4), metres), the method that found it, and its overlap."""

    cad_from_cloud: np.ndarray
    method: str
    overlap: float


def coarse_alignment(points_m: np.ndarray, index: CadIndex, size_m: float, rng: np.random.Generator,
                     method: str = "auto") -> CoarseResult:
    """Find ``cad_from_cloud`` from any starting pose.

    Parameters
    ----------
    points_m : (N, 3) float array
        Cloud, metres (outliers allowed).
    index : CadIndex
        The CAD surface.
    size_m : float
        The CAD's bounding-box diagonal, metres (sets the voxel size).
    rng : numpy.random.Generator
        Draws subsamples, random starts and Open3D's RANSAC seed.
    method : {"auto", "features", "multistart"}
        ``auto``: the feature match (when Open3D is importable) and the multi-start finalists all
        compete; the others use one method only.

    Returns
    -------
    CoarseResult
        The candidate whose robust ICP on :data:`CHECK_POINTS` points keeps the most points.
    """
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    voxel_m = size_m / VOXELS_ACROSS
    # A bounded subsample: the number of voxels that scattered outliers occupy grows with the
    # cloud (100 000 outliers fill every voxel around a part), the surface's does not.
    if len(points_m) > COARSE_POINTS:
        points_m = points_m[rng.choice(len(points_m), COARSE_POINTS, replace=False)]
    check = points_m[rng.choice(len(points_m), min(CHECK_POINTS, len(points_m)), replace=False)]
    sparse = index.sparse(TRIAL_SAMPLES, rng)
    starts = []
    if method == "features" or (method == "auto" and _open3d() is not None):
        starts.append(("features", _features(points_m, index, voxel_m, rng)))
    if method in ("auto", "multistart"):
        starts += [("multistart", m) for m in _multistart(points_m, sparse, size_m, rng)]
    return max((_refine(check, index, sparse, start, name, size_m) for name, start in starts),
               key=lambda r: r.overlap)


def _open3d():
    """The open3d module, or None when the optional extra is not installed."""
    try:
        import open3d
    except ImportError:
        return None
    return open3d


def _refine(points_m, index, sparse, start, method, size_m) -> CoarseResult:
    """Trimmed then robust ICP (sparse samples) from ``start``, and the :func:`overlap` it reaches."""
    fit = robust_icp(points_m, sparse, start, weight_fn=trimmed_weights(TRIM_KEEP), size_m=size_m,
                     max_iterations=TRIAL_ITERATIONS)
    fit = robust_icp(points_m, sparse, fit.cad_from_cloud, size_m=size_m, max_iterations=TRIAL_ITERATIONS)
    return CoarseResult(fit.cad_from_cloud, method, overlap(points_m, index, fit.cad_from_cloud, size_m))


def overlap(points_m: np.ndarray, index: CadIndex, cad_from_cloud: np.ndarray, size_m: float) -> float:
    """Fraction of the points that ``cad_from_cloud`` brings within :data:`OVERLAP_FRACTION` x ``size_m`` of the CAD."""
    moved = points_m @ cad_from_cloud[:3, :3].T + cad_from_cloud[:3, 3]
    return float(np.mean(index.closest(moved).distance_m < OVERLAP_FRACTION * size_m))


def _features(points_m, index, voxel_m, rng) -> np.ndarray:
    """FPFH + RANSAC (Open3D) from the cloud to the CAD samples; returns cad_from_cloud."""
    o3d = _open3d()
    if o3d is None:
        raise ImportError('coarse alignment by features needs Open3D: pip install "scanrig[open3d]"')
    reg = o3d.pipelines.registration
    o3d.utility.random.seed(int(rng.integers(2**31 - 1)))

    def prepared(xyz):
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz)).voxel_down_sample(voxel_m)
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=NORMAL_RADIUS_VOXELS * voxel_m, max_nn=30))
        feature = reg.compute_fpfh_feature(
            cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=FEATURE_RADIUS_VOXELS * voxel_m, max_nn=100))
        return cloud, feature

    source, source_f = prepared(points_m)
    target, target_f = prepared(index.sample_m)
    distance = RANSAC_DISTANCE_VOXELS * voxel_m
    result = reg.registration_ransac_based_on_feature_matching(
        source, target, source_f, target_f, True, distance,
        reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(distance)],
        reg.RANSACConvergenceCriteria(RANSAC_ITERATIONS, RANSAC_CONFIDENCE))
    return np.asarray(result.transformation, np.float64).copy()


def _principal_axes(xyz: np.ndarray) -> np.ndarray:
    """Rows: principal axes, largest spread first, as a proper rotation."""
    _, _, axes = np.linalg.svd(xyz - xyz.mean(axis=0), full_matrices=False)
    if np.linalg.det(axes) < 0:
        axes[2] *= -1
    return axes


def _multistart(points_m, index, size_m, rng) -> list[np.ndarray]:
    """Trimmed ICP on a few hundred points from many rotations; the :data:`FINALISTS` best transforms.

    ``index`` is the sparse index (the trials start far from the surface).
    """
    trial = points_m[rng.choice(len(points_m), min(TRIAL_POINTS, len(points_m)), replace=False)]
    cad_axes = _principal_axes(index.sample_m[:: max(1, len(index.sample_m) // 20_000)])
    cloud_axes = _principal_axes(trial)
    rotations = [np.eye(3)] + [cad_axes.T @ g @ cloud_axes for g in Rotation.create_group("O").as_matrix()]
    rotations += list(Rotation.random(RANDOM_STARTS, random_state=rng).as_matrix())
    cad_centre = index.sample_m.mean(axis=0)
    cloud_centre = np.median(points_m, axis=0)
    starts = np.broadcast_to(np.eye(4), (len(rotations), 4, 4)).copy()
    starts[:, :3, :3] = rotations
    starts[:, :3, 3] = cad_centre - starts[:, :3, :3] @ cloud_centre
    fits = icp_trials(trial, index, starts, weight_fn=trimmed_weights(TRIM_KEEP), size_m=size_m,
                      max_iterations=TRIAL_ITERATIONS).cad_from_cloud
    moved = trial @ fits[:, :3, :3].transpose(0, 2, 1) + fits[:, None, :3, 3]
    d = np.sort(index.nearest_sample_distance(moved.reshape(-1, 3)).reshape(len(fits), -1), axis=1)
    d = d[:, : int(TRIM_KEEP * len(trial))]
    score = np.sqrt(np.mean(d * d, axis=1))
    return list(fits[np.argsort(score, kind="stable")[:FINALISTS]])
