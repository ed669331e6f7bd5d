"""The observation table: one row per detected target point in one image.

Columns: camera index, shot index, target point id, pixel ``(u, v)`` and a weight (inverse
variance relative to the common pixel noise: 1 for an ordinary detection). A *view* is the set of
rows of one camera in one shot; a *shot* is one pose of the target (same image stem in every
camera).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError, ShapeError


@dataclass(frozen=True)
class Observations:
    """Detected target points of a whole calibration.

    Attributes
    ----------
    camera : ndarray of shape (N,), int64
        Index into :attr:`camera_names`.
    shot : ndarray of shape (N,), int64
        Index into :attr:`shot_names`.
    point_id : ndarray of shape (N,), int64
        Target point id (``Target.point_ids``).
    uv : ndarray of shape (N, 2), float64
        Pixels ``(u, v)``; pixel (0, 0) is the centre of the top-left pixel.
    weight : ndarray of shape (N,), float64
        Relative inverse variance of the detection (> 0).
    camera_names, shot_names : tuple of str
        Camera names in rig order; shot stems in natural order.
    image_sizes : dict
        ``camera name -> (width, height)`` in pixels.
    """

    camera: np.ndarray
    shot: np.ndarray
    point_id: np.ndarray
    uv: np.ndarray
    weight: np.ndarray
    camera_names: tuple[str, ...]
    shot_names: tuple[str, ...]
    image_sizes: dict

    def __post_init__(self):
        n = len(self.camera)
        for name in ("camera", "shot", "point_id"):
            arr = np.asarray(getattr(self, name), dtype=np.int64).ravel()
            if arr.shape != (n,):
                raise ShapeError(f"observations {name} must have shape ({n},), got {arr.shape}")
            object.__setattr__(self, name, arr)
        uv = np.asarray(self.uv, dtype=np.float64)
        if uv.shape != (n, 2):
            raise ShapeError(f"observations uv must have shape ({n}, 2), got {uv.shape}")
        weight = np.asarray(self.weight, dtype=np.float64).ravel()
        if weight.shape != (n,):
            raise ShapeError(f"observations weight must have shape ({n},), got {weight.shape}")
        if not np.all(np.isfinite(uv)):
            raise InputError("observations uv must be finite (drop undetected points instead of NaN)")
        if np.any(~(weight > 0)):
            raise InputError("observation weights must be positive")
        object.__setattr__(self, "uv", uv)
        object.__setattr__(self, "weight", weight)
        object.__setattr__(self, "camera_names", tuple(self.camera_names))
        object.__setattr__(self, "shot_names", tuple(self.shot_names))
        if n and (self.camera.min() < 0 or self.camera.max() >= len(self.camera_names)):
            raise InputError("observation camera index out of range")
        if n and (self.shot.min() < 0 or self.shot.max() >= len(self.shot_names)):
            raise InputError("observation shot index out of range")
        missing = [c for c in self.camera_names if c not in self.image_sizes]
        if missing:
            raise InputError(f"image_sizes lacks cameras {missing}")

    def __len__(self) -> int:
        return len(self.camera)

    def subset(self, mask) -> Observations:
        """Rows where ``mask`` (bool (N,) or index array) selects; names and sizes are kept."""
        return Observations(self.camera[mask], self.shot[mask], self.point_id[mask], self.uv[mask],
                            self.weight[mask], self.camera_names, self.shot_names, self.image_sizes)

    def view_counts(self) -> np.ndarray:
        """``(n_cameras, n_shots)`` number of observations of each view."""
        counts = np.zeros((len(self.camera_names), len(self.shot_names)), dtype=np.int64)
        np.add.at(counts, (self.camera, self.shot), 1)
        return counts

    def camera_counts(self) -> dict[str, int]:
        """``camera name -> number of observations``."""
        counts = np.bincount(self.camera, minlength=len(self.camera_names))
        return {name: int(c) for name, c in zip(self.camera_names, counts)}

    @classmethod
    def concatenate(cls, parts: list[tuple[str, str, np.ndarray, np.ndarray, np.ndarray]],
                    camera_names, shot_names, image_sizes) -> Observations:
        """Build the table from per-view parts ``(camera, shot, point_ids (n,), uv (n, 2), weight (n,))``."""
        cam_index = {c: i for i, c in enumerate(camera_names)}
        shot_index = {s: i for i, s in enumerate(shot_names)}
        if not parts:
            empty = np.zeros(0, dtype=np.int64)
            return cls(empty, empty, empty, np.zeros((0, 2)), np.zeros(0), camera_names, shot_names, image_sizes)
        cams = np.concatenate([np.full(len(p[2]), cam_index[p[0]]) for p in parts])
        shots = np.concatenate([np.full(len(p[2]), shot_index[p[1]]) for p in parts])
        return cls(cams, shots, np.concatenate([p[2] for p in parts]), np.concatenate([p[3] for p in parts]),
                   np.concatenate([p[4] for p in parts]), camera_names, shot_names, image_sizes)
