"""The reconstructed point cloud and its file, ``points.ply`` (``docs/architecture.md``).

Binary little-endian PLY with vertex fields ``x, y, z`` (float64, metres, world frame),
``sigma`` (float64, metres, standard deviation along the covariance's largest axis),
``n_views`` (uint8), ``residual_px`` (float32), ``frame`` (int32, index of the frame stem in
natural order) and ``flags`` (uint16, :class:`~scanrig.reconstruct.flags.Flag`). Header comments
state units, frame and the run's seed; Open3D, MeshLab and CloudCompare read the file (they
ignore the extra fields or show them as scalar fields).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError

#: Vertex fields of ``points.ply`` and their types, in file order.
POINT_FIELDS = (
    ("x", np.float64), ("y", np.float64), ("z", np.float64), ("sigma", np.float64),
    ("n_views", np.uint8), ("residual_px", np.float32), ("frame", np.int32), ("flags", np.uint16),
)
UNITS_COMMENT = "units: metres (x, y, z, sigma), pixels (residual_px); frame: world frame of rig.toml"


@dataclass(frozen=True)
class PointCloud:
    """Reconstructed points with per-point quality (all arrays have N rows).

    Attributes
    ----------
    p_world : ndarray of shape (N, 3)
        Points, world frame, metres.
    sigma : ndarray of shape (N,)
        Standard deviation along the largest axis of the point's covariance, metres.
    n_views : ndarray of shape (N,), uint8
        Cameras used (1 for points intersected with a light plane).
    residual_px : ndarray of shape (N,), float32
        RMS reprojection residual over the views, pixels.
    frame : ndarray of shape (N,), int32
        Index of the frame stem in natural order.
    flags : ndarray of shape (N,), uint16
        :class:`~scanrig.reconstruct.flags.Flag` bits.
    """

    p_world: np.ndarray
    sigma: np.ndarray
    n_views: np.ndarray
    residual_px: np.ndarray
    frame: np.ndarray
    flags: np.ndarray

    def __post_init__(self):
        casts = dict(POINT_FIELDS)
        object.__setattr__(self, "p_world", np.asarray(self.p_world, np.float64).reshape(-1, 3))
        for name in ("sigma", "n_views", "residual_px", "frame", "flags"):
            object.__setattr__(self, name, np.asarray(getattr(self, name)).astype(casts[name]))

    def __len__(self) -> int:
        return self.p_world.shape[0]

    @classmethod
    def empty(cls) -> PointCloud:
        return cls(np.zeros((0, 3)), [], [], [], [], [])

    @classmethod
    def concatenate(cls, clouds) -> PointCloud:
        """One cloud with the points of several, in order."""
        clouds = list(clouds) or [cls.empty()]
        return cls(*(np.concatenate([getattr(c, name) for c in clouds])
                     for name in ("p_world", "sigma", "n_views", "residual_px", "frame", "flags")))

    def select(self, mask: np.ndarray) -> PointCloud:
        """The points where ``mask`` (or at the indices) holds."""
        return PointCloud(self.p_world[mask], self.sigma[mask], self.n_views[mask], self.residual_px[mask],
                          self.frame[mask], self.flags[mask])

    def vertex_fields(self) -> dict[str, np.ndarray]:
        """``name -> (N,) array`` in :data:`POINT_FIELDS` order and types."""
        values = {"x": self.p_world[:, 0], "y": self.p_world[:, 1], "z": self.p_world[:, 2],
                  "sigma": self.sigma, "n_views": self.n_views, "residual_px": self.residual_px,
                  "frame": self.frame, "flags": self.flags}
        return {name: np.ascontiguousarray(values[name], dtype) for name, dtype in POINT_FIELDS}


def write_points(path: str | Path, cloud: PointCloud, comments=()) -> None:
    """Write ``points.ply`` atomically (binary little-endian) with a units/frame comment.

    Parameters
    ----------
    path : str or Path
        Output file.
    cloud : PointCloud
    comments : iterable of str
        Extra header comments (seed, command line, counts), one line each.
    """
    from scanrig.io.ply import write_ply

    write_ply(path, cloud.vertex_fields(), comments=(UNITS_COMMENT, *comments), binary=True)


def read_points(path: str | Path) -> tuple[PointCloud, list[str]]:
    """Read a ``points.ply``; returns the cloud and the header comments.

    Raises
    ------
    FileFormatError
        If the file lacks ``x, y, z``. Missing quality fields (a cloud from another tool) are
        filled with NaN / 0.
    """
    from scanrig.io.ply import read_ply

    vertices, _, comments = read_ply(path)
    missing = [name for name in ("x", "y", "z") if name not in vertices]
    if missing:
        raise FileFormatError(path, f"vertex fields {missing} are missing")
    n = len(vertices["x"])

    def field(name, default):
        return vertices[name] if name in vertices else np.full(n, default)

    cloud = PointCloud(np.stack([vertices["x"], vertices["y"], vertices["z"]], axis=1), field("sigma", np.nan),
                       field("n_views", 0), field("residual_px", np.nan), field("frame", -1), field("flags", 0))
    return cloud, list(comments)

