"""One camera's stripe detections in one frame: rays, neighbour segments, tangents, across-noise."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

#: Two detections of one camera closer than this (pixels), and not on the same scan line, are
#: neighbours on a stripe: samples are one pixel apart along the scan direction, sqrt(2) on a 45°
#: stripe, and up to ~2.7 px for a stripe at 70° to its scan lines.
NEIGHBOUR_PX = 3.0
#: Half-length (pixels) of the piece of tangent used to back-project a stripe's local line.
TANGENT_STEP_PX = 2.0


def neighbour_segments(q: np.ndarray, line: np.ndarray, rows: np.ndarray,
                       usable: np.ndarray | None = None) -> np.ndarray:
    """Pairs ``(m, 2)`` of detections that are neighbours on a stripe: closer than
    ``NEIGHBOUR_PX`` and not on the same scan line (``line`` with ``rows`` telling rows from
    columns), both ``usable`` (default: all)."""
    n = len(q)
    pairs = cKDTree(q).query_pairs(NEIGHBOUR_PX, output_type="ndarray") if n > 1 else np.zeros((0, 2), int)
    keep = (line[pairs[:, 0]] != line[pairs[:, 1]]) | (rows[pairs[:, 0]] != rows[pairs[:, 1]])
    if usable is not None:
        keep &= usable[pairs[:, 0]] & usable[pairs[:, 1]]
    return pairs[keep]


def stripe_pieces(n: int, segments: np.ndarray) -> np.ndarray:
    """Label ``(n,)`` of the piece of stripe each detection belongs to: the connected components of
    the neighbour graph ``segments``."""
    if n == 0:
        return np.zeros(0, int)
    graph = coo_matrix((np.ones(len(segments)), (segments[:, 0], segments[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


class StripeView:
    """One camera's stripe detections in one frame: rays, segments, tangents and across-noise."""

    def __init__(self, cam, q, cov, rank, saturated, line=None, rows=None):
        n = len(q)
        self.cam = cam
        self.q, self.cov, self.rank, self.saturated = q, cov, rank, saturated
        line = np.arange(n) if line is None else np.asarray(line)
        rows = np.ones(n, bool) if rows is None else np.asarray(rows, bool)
        xy, _ = cam.unproject(q) if n else (np.zeros((0, 2)), None)
        R = cam.cam_from_world.R
        d_cam = np.c_[xy, np.ones(n)]
        d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
        self.xh = np.c_[xy, np.ones(n)]  # homogeneous normalised coordinates
        self.dirs = d_cam @ R  # world directions (R.T applied to row vectors)
        finite = np.all(np.isfinite(xy), axis=1)
        self.segments = neighbour_segments(q, line, rows, finite)
        # Local tangent: principal direction of the differences to the neighbours.
        s0, s1 = self.segments[:, 0], self.segments[:, 1]
        diff = q[s1] - q[s0]
        outer = diff[:, :, None] * diff[:, None, :]
        M = np.zeros((n, 2, 2))
        np.add.at(M, s0, outer)
        np.add.at(M, s1, outer)
        angle = 0.5 * np.arctan2(2.0 * M[:, 0, 1], M[:, 0, 0] - M[:, 1, 1])
        self.tangent = np.c_[np.cos(angle), np.sin(angle)]
        self.normal = np.c_[-self.tangent[:, 1], self.tangent[:, 0]]
        self.has_tangent = finite & (np.bincount(self.segments.ravel(), minlength=n) > 0)
        self.var_perp = np.einsum("ni,nij,nj->n", self.normal, cov, self.normal)
        self._lines = None
        self.piece = stripe_pieces(n, self.segments)

    def inflate(self, extra_var_px2: np.ndarray) -> None:
        """Add an isotropic variance (px², one per detection) to the covariances, in place."""
        self.cov = self.cov + extra_var_px2[:, None, None] * np.eye(2)
        self.var_perp = self.var_perp + extra_var_px2

    def lines(self) -> np.ndarray:
        """``(n, 3)`` back-projected local stripe lines in normalised coordinates, ``|l[:2]| = 1``."""
        if self._lines is None:
            step = TANGENT_STEP_PX * self.tangent
            xa, _ = self.cam.unproject(self.q - step) if len(self.q) else (np.zeros((0, 2)), None)
            xb, _ = self.cam.unproject(self.q + step) if len(self.q) else (np.zeros((0, 2)), None)
            lines = np.cross(np.c_[xa, np.ones(len(xa))], np.c_[xb, np.ones(len(xb))])
            with np.errstate(invalid="ignore", divide="ignore"):
                self._lines = lines / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
        return self._lines



def frame_views(rig, table_frame: pa.Table, floor_cov):
    views = []
    for cam in rig.cameras:
        rows = table_frame.filter(pc.equal(table_frame.column("camera"), cam.name))

        def col(name, rows=rows):
            return rows.column(name).to_numpy()

        n = rows.num_rows
        q = np.c_[col("u"), col("v")] if n else np.zeros((0, 2))
        cov = np.zeros((n, 2, 2))
        if n:
            cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1] = col("cov_uu"), col("cov_uv"), col("cov_vv")
            cov[:, 1, 0] = cov[:, 0, 1]
        line = col("line") if n else np.zeros(0, int)
        scan_rows = cov[:, 1, 1] <= cov[:, 0, 0]  # rows scanned: v exact (cov_vv = 0)
        views.append(StripeView(cam, q, cov + floor_cov, col("rank") if n else np.zeros(0, int),
                           col("saturated") if n else np.zeros(0, bool), line, scan_rows))
    return views

