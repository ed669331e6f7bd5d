"""Distance of reconstructed points to a true surface (simulator ``truth/meshes/*.ply``).

**One definition of accuracy** (``scanrig evaluate``, ``scanrig demo`` and ``report.html`` all
call :func:`session_accuracy`): the RMS of the distances of *all* points of ``points.ply`` to the
true surface, in the world frame of ``rig.toml``; after the filter, the same over the points it
kept (``surface.ply`` inliers, at their denoised positions), with the number it removed. No point
is set aside before the RMS, and no frame is fitted to the truth: a rig whose world frame is the
scene's (``[metadata] world_frame = "scene"``, as the demo writes) is compared as it is; another
calibration's frame is tied to ``truth/rig.toml`` through the camera poses (:func:`rig_alignment`),
which carries the calibration's pose errors into the figure.

The exact point–triangle distance (Ericson, *Real-Time Collision Detection*, §5.1.5) is evaluated
only for triangles that can be the nearest: the mesh is first subdivided so that no edge exceeds
``max_edge_m``, the nearest centroids (KD-tree) give an upper bound ``d0`` of the distance, and
a triangle is checked only if the sphere about its centroid through its farthest corner comes
within ``d0`` of the point (its centroid is then within ``d0`` plus the largest such radius, which
bounds the KD-tree's search). trimesh's own ``proximity`` module needs the optional ``rtree``
package, which scanrig does not depend on.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from scanrig.errors import FileFormatError, InputError

#: Longest triangle edge after subdivision; bounds the search radius beyond the first guess.
MAX_EDGE_M = 0.005
#: Nearest centroids used for the first upper bound of the distance.
FIRST_GUESS_K = 4
#: Distance beyond which a point counts as an outlier in the statistics (the brief's 1 mm).
OUTLIER_DISTANCE_M = 1e-3
#: Points per block of the exact search (bounds memory).
BLOCK_POINTS = 20000
#: Coverage: a piece of true surface is covered when a reconstructed point lies within this distance.
COVERAGE_DISTANCE_M = 0.005
#: Area-weighted samples of the true surface for the coverage (quadrature error ~ 1 / sqrt(n), 0.3 %).
COVERAGE_SAMPLES = 100_000
#: ``[metadata] world_frame`` of a rig.toml whose world frame is already the simulator's scene frame.
SCENE_WORLD_FRAME = "scene"


def point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Euclidean distance from points to triangles, row by row.

    Parameters
    ----------
    p, a, b, c : ndarray of shape (M, 3)
        Points and triangle corners, metres.

    Returns
    -------
    ndarray of shape (M,)
        Distance from ``p[i]`` to triangle ``(a[i], b[i], c[i])``, metres.
    """
    def dot(x, y):
        return np.einsum("ij,ij->i", x, y)

    ab, ac, ap = b - a, c - a, p - a
    bp, cp = p - b, p - c
    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        closest = a + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]  # inside the face
        # Voronoi regions in reverse order of Ericson's tests, so that his first test wins.
        regions = [
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
             b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None]),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * (d2 / (d2 - d6))[:, None]),
            ((d6 >= 0) & (d5 <= d6), c),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * (d1 / (d1 - d3))[:, None]),
            ((d3 >= 0) & (d4 <= d3), b),
            ((d1 <= 0) & (d2 <= 0), a),
        ]
    for mask, point in regions:
        closest = np.where(mask[:, None], point, closest)
    return np.linalg.norm(p - closest, axis=1)


@dataclass(frozen=True)
class SurfaceDistance:
    """Unsigned distance to a triangle mesh.

    Parameters
    ----------
    vertices : ndarray of shape (V, 3)
        Mesh vertices, metres.
    faces : ndarray of shape (F, 3), int
        Triangles.
    max_edge_m : float
        Subdivision size (see the module notes).
    """

    vertices: np.ndarray
    faces: np.ndarray
    max_edge_m: float = MAX_EDGE_M

    def __post_init__(self):
        import trimesh

        v, f = trimesh.remesh.subdivide_to_size(np.asarray(self.vertices, np.float64),
                                                np.asarray(self.faces, np.int64), self.max_edge_m)
        tri = v[f]
        centroid = tri.mean(axis=1)
        object.__setattr__(self, "_tri", tri)
        object.__setattr__(self, "_centroid", centroid)
        # radius of the sphere about each centroid that holds its triangle (<= 2/3 of its longest edge)
        object.__setattr__(self, "_reach", np.linalg.norm(tri - centroid[:, None], axis=2).max(axis=1))
        object.__setattr__(self, "_tree", cKDTree(centroid))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``(n, 3)`` points drawn uniformly over the surface's area, metres."""
        tri = self._tri
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        pick = rng.choice(len(tri), n, p=area / area.sum())
        u, v = rng.random((2, n))
        flip = u + v > 1                      # fold the unit square onto the triangle
        u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
        a, b, c = tri[pick].transpose(1, 0, 2)
        return a + (b - a) * u[:, None] + (c - a) * v[:, None]

    def __call__(self, p_world: np.ndarray) -> np.ndarray:
        """Distances ``(N,)`` (metres) of points ``(N, 3)`` to the surface."""
        p_world = np.asarray(p_world, np.float64)
        out = np.empty(p_world.shape[0])
        for start in range(0, p_world.shape[0], BLOCK_POINTS):
            out[start:start + BLOCK_POINTS] = self._block(p_world[start:start + BLOCK_POINTS])
        return out

    def _block(self, p: np.ndarray) -> np.ndarray:
        tri = self._tri
        k = min(FIRST_GUESS_K, len(tri))
        _, near = self._tree.query(p, k=k)
        near = near.reshape(len(p), k)
        rows = np.repeat(np.arange(len(p)), k)
        d0 = point_triangle_distance(p[rows], *tri[near.ravel()].transpose(1, 0, 2)).reshape(len(p), k).min(axis=1)
        # A triangle closer than d0 to p has a point x with |p - x| < d0 and |x - centroid| <= reach:
        # its centroid lies within d0 + reach of p.
        lists = self._tree.query_ball_point(p, d0 + self._reach.max(), return_sorted=False)
        counts = np.fromiter(map(len, lists), np.int64, len(lists))
        cand = np.fromiter(itertools.chain.from_iterable(lists), np.int64, int(counts.sum()))
        rows = np.repeat(np.arange(len(p)), counts)
        can_beat = np.linalg.norm(p[rows] - self._centroid[cand], axis=1) - self._reach[cand] < d0[rows]
        rows, cand = rows[can_beat], cand[can_beat]
        d = point_triangle_distance(p[rows], *tri[cand].transpose(1, 0, 2))
        best = np.full(len(p), np.inf)
        np.minimum.at(best, rows, d)
        return np.minimum(best, d0)


def load_truth_surface(truth_dir: str | Path) -> SurfaceDistance:
    """The union of the simulator's true meshes ``truth/meshes/*.ply`` as a distance function.

    Raises
    ------
    FileFormatError
        If the folder holds no mesh.
    """
    import trimesh

    folder = Path(truth_dir) / "meshes"
    paths = sorted(folder.glob("*.ply")) if folder.is_dir() else []
    if not paths:
        raise FileFormatError(folder, "no true meshes (*.ply) found; --truth must be a simulator truth/ folder")
    vertices, faces, offset = [], [], 0
    for path in paths:
        try:
            mesh = trimesh.load(path, force="mesh", process=False)
        except Exception as exc:  # noqa: BLE001 - trimesh raises many types for broken files
            raise FileFormatError(path, f"cannot read mesh: {exc}") from None
        if not len(mesh.faces):
            raise FileFormatError(path, "mesh file holds no triangles")
        vertices.append(np.asarray(mesh.vertices, np.float64))
        faces.append(np.asarray(mesh.faces, np.int64) + offset)
        offset += len(mesh.vertices)
    return SurfaceDistance(np.concatenate(vertices), np.concatenate(faces))


def rig_alignment(rig_estimated, rig_true):
    """The rigid transform ``true_from_estimated`` that best maps one rig's world onto another's.

    A calibration defines its own world frame (the target at its first pose); to compare its
    points with the simulator's truth, the frames are tied through the cameras themselves: each
    camera gives ``true_from_est = cam_true⁻¹ ∘ cam_est``, and the rotations are averaged
    (projection of their sum onto SO(3)) and the camera centres fitted in least squares.

    Parameters
    ----------
    rig_estimated, rig_true : Rig
        Rigs with the same camera names.

    Returns
    -------
    RigidTransform
    """
    from scanrig.geometry.transform import RigidTransform

    names = [n for n in rig_estimated.names if n in rig_true]
    if len(names) < 2:
        raise InputError(f"rig alignment needs 2 or more cameras in common, got {names}")
    M = sum((rig_true[n].cam_from_world.inverse() @ rig_estimated[n].cam_from_world).R for n in names)
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    c_est = np.array([rig_estimated[n].center_world for n in names])
    c_true = np.array([rig_true[n].center_world for n in names])
    t = (c_true - c_est @ R.T).mean(axis=0)
    return RigidTransform(R, t)


def distance_statistics(distance_m: np.ndarray, outlier_m: float = OUTLIER_DISTANCE_M) -> dict:
    """RMS, mean, 95th/99th percentile, maximum and fraction beyond ``outlier_m`` of distances (metres)."""
    d = np.asarray(distance_m, np.float64)
    if d.size == 0:
        raise InputError("no points to evaluate")
    return {
        "n_points": int(d.size),
        "rms_m": float(np.sqrt(np.mean(d**2))),
        "mean_m": float(np.mean(d)),
        "p95_m": float(np.percentile(d, 95)),
        "p99_m": float(np.percentile(d, 99)),
        "max_m": float(np.max(d)),
        "fraction_beyond": float(np.mean(d > outlier_m)),
        "outlier_m": float(outlier_m),
    }


def save_histogram(distance_m: np.ndarray, path: str | Path, title: str = "") -> None:
    """Histogram of distances in millimetres (log counts), written atomically as PNG."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from scanrig.io.atomic import write_bytes_atomic

    d_mm = np.asarray(distance_m) * 1e3
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.hist(d_mm, bins=100, log=True, color="tab:blue")
    ax.axvline(OUTLIER_DISTANCE_M * 1e3, color="tab:red", ls="--", label="1 mm")
    ax.set_xlabel("distance to true surface (mm)")
    ax.set_ylabel("points")
    ax.set_title(title or f"{d_mm.size} points, RMS {np.sqrt(np.mean(d_mm**2)):.3f} mm")
    ax.legend()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())


@dataclass(frozen=True)
class SessionAccuracy:
    """Accuracy of a session's clouds against the simulator's truth (see the module notes).

    Attributes
    ----------
    distance_m : (N,) float array
        Distance of every point of ``points.ply`` to the true surface, metres.
    before : dict
        :func:`distance_statistics` of ``distance_m``.
    after : dict or None
        The same for the points the filter kept (None without a matching ``surface.ply``).
    n_removed : int or None
        Points the filter removed.
    n_filter_input : int or None
        Points the filter was given (``surface.ply`` holds one vertex per input point): all of
        ``points.ply``, or a random subsample of it when the cloud was too large for its time.
    coverage : float
        Fraction of the true surface's area inside the cloud's bounding box that lies within
        :data:`COVERAGE_DISTANCE_M` of a point (surfaces no camera can see count as uncovered).
    alignment : str
        How the cloud's frame was tied to the truth's.
    median_sigma_m : float
        Median predicted sigma of the points (NaN when the file carries none), metres.
    surface_note : str
        Why ``after`` is None, or "".
    """

    distance_m: np.ndarray
    before: dict
    after: dict | None
    n_removed: int | None
    n_filter_input: int | None
    coverage: float
    alignment: str
    median_sigma_m: float
    surface_note: str = ""

    def lines(self) -> list[str]:
        """The figures as the lines ``scanrig evaluate`` prints."""
        b = self.before
        out = [f"{b['n_points']} points: {_stats_text(b)}"]
        if self.after is not None:
            subset = (f" (the filter's input: {self.n_filter_input} of the {b['n_points']} points, drawn at random)"
                      if self.n_filter_input != b["n_points"] else "")
            out.append(f"after the filter: {self.after['n_points']} kept, {self.n_removed} removed{subset}: "
                       f"{_stats_text(self.after)}")
        elif self.surface_note:
            out.append(f"after the filter: {self.surface_note}")
        out.append(f"coverage: {100 * self.coverage:.1f} % of the true surface in the cloud's bounding box "
                   f"lies within {COVERAGE_DISTANCE_M * 1e3:g} mm of a point")
        return out


def _stats_text(stats: dict) -> str:
    return (f"RMS {stats['rms_m'] * 1e3:.4f} mm, mean {stats['mean_m'] * 1e3:.4f} mm, "
            f"p95 {stats['p95_m'] * 1e3:.4f} mm, p99 {stats['p99_m'] * 1e3:.4f} mm, max {stats['max_m'] * 1e3:.4f} mm, "
            f"{100 * stats['fraction_beyond']:.3f} % beyond {stats['outlier_m'] * 1e3:g} mm")


def session_accuracy(points_path: str | Path, truth_dir: str | Path, *, rig_path: str | Path | None = None,
                     surface_path: str | Path | None = None, outlier_m: float = OUTLIER_DISTANCE_M,
                     truth: SurfaceDistance | None = None, rng: np.random.Generator | None = None
                     ) -> SessionAccuracy:
    """The accuracy of ``points.ply`` (and of the filter's ``surface.ply``) against the truth.

    Parameters
    ----------
    points_path : str or Path
        The cloud: ``points.ply`` or any PLY with ``x, y, z`` in metres. Every point counts.
    truth_dir : str or Path
        The simulator's ``truth/`` folder (``meshes/*.ply``, ``rig.toml`` for an alignment).
    rig_path : str or Path, optional
        The rig the points were reconstructed with. When its ``[metadata] world_frame`` is
        :data:`SCENE_WORLD_FRAME` (or it is None) the points are compared as they are; otherwise
        its world frame is tied to ``truth/rig.toml`` by :func:`rig_alignment`.
    surface_path : str or Path, optional
        The filter's ``surface.ply`` of this cloud (one vertex per point it was given, ``inlier`` 0/1).
    outlier_m : float
        Distance counted as beyond, metres.
    truth : SurfaceDistance, optional
        The true surface, when the caller has it loaded already.
    rng : numpy.random.Generator, optional
        Draws the coverage's surface samples (default: seeded with 0, so the figure is repeatable).

    Returns
    -------
    SessionAccuracy

    Raises
    ------
    FileFormatError
        No true meshes, an unreadable cloud, or a ``surface.ply`` without ``x, y, z``.
    """
    from scanrig.io.ply import read_ply
    from scanrig.io.rig_file import load_rig, load_rig_info
    from scanrig.reconstruct.points import read_points

    truth_dir = Path(truth_dir)
    truth = truth if truth is not None else load_truth_surface(truth_dir)
    cloud, _ = read_points(points_path)
    align, alignment = None, "rig.toml's world frame, compared as it is"
    if rig_path is not None:
        rig, _, metadata = load_rig_info(rig_path)
        if metadata.get("world_frame") == SCENE_WORLD_FRAME:
            alignment = f"{Path(rig_path).name} is in the scene frame (world_frame = {SCENE_WORLD_FRAME!r}): no alignment"
        else:
            align = rig_alignment(rig, load_rig(truth_dir / "rig.toml"))
            alignment = f"{Path(rig_path).name} tied to truth/rig.toml through the camera poses"
    p_world = cloud.p_world if align is None else align.apply(cloud.p_world)
    distance = truth(p_world)
    after = n_removed = n_input = None
    note = ""
    if surface_path is not None and Path(surface_path).is_file():
        # One vertex per point the filter was given, at its denoised position, flagged inlier 0/1.
        vertices, _, _ = read_ply(surface_path)
        n_input = len(vertices["x"])
        keep = vertices["inlier"] != 0 if "inlier" in vertices else np.ones(n_input, bool)
        kept = np.column_stack([vertices[k][keep].astype(np.float64) for k in ("x", "y", "z")])
        kept = kept if align is None else align.apply(kept)
        n_removed = int(n_input - keep.sum())
        after = distance_statistics(truth(kept), outlier_m) if len(kept) else None
        note = "" if len(kept) else "the filter kept no point"
    elif surface_path is not None:
        note = f"no {Path(surface_path).name}"
    coverage = surface_coverage(truth, p_world, rng or np.random.default_rng(0))
    sigma = cloud.sigma[np.isfinite(cloud.sigma)]
    return SessionAccuracy(distance, distance_statistics(distance, outlier_m), after, n_removed, n_input, coverage,
                           alignment, float(np.median(sigma)) if len(sigma) else float("nan"), note)


def surface_coverage(truth: SurfaceDistance, p_world: np.ndarray, rng: np.random.Generator,
                     n_samples: int = COVERAGE_SAMPLES, radius_m: float = COVERAGE_DISTANCE_M) -> float:
    """Fraction of the true surface inside the cloud's bounding box within ``radius_m`` of a point.

    Parameters
    ----------
    truth : SurfaceDistance
    p_world : (N, 3) float array
        The cloud, metres.
    rng : numpy.random.Generator
        Draws the area-weighted surface samples.
    n_samples : int
        Samples of the whole true surface.
    radius_m : float

    Returns
    -------
    float
        In [0, 1]; 0 for an empty cloud or a box that holds no sample.
    """
    if len(p_world) == 0:
        return 0.0
    samples = truth.sample(n_samples, rng)
    inside = np.all((samples >= p_world.min(axis=0) - radius_m) & (samples <= p_world.max(axis=0) + radius_m), axis=1)
    if not inside.any():
        return 0.0
    d, _ = cKDTree(p_world).query(samples[inside], distance_upper_bound=radius_m)
    return float(np.mean(np.isfinite(d)))
