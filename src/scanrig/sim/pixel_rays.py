"""Lines of sight of many pixels, fast.

``Camera.rays`` is general (it checks every solution against the fold of the distortion map)
and costs tens of microseconds per pixel; a simulator casts millions of camera rays per image.
Here OpenCV's iterative ``undistortPoints`` (run to its float64 limit) solves every pixel, each
solution is checked by re-distorting it with the foundation's exact model, and the few pixels
that do not reproduce their coordinates to :data:`_RESIDUAL_TOL` fall back to
``Camera.unproject``.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

from scanrig.geometry import Camera
from scanrig.geometry import distortion

#: Reprojection residual (normalised coordinates) below which a fast solution is accepted;
#: 1e-12 is ~2e-9 px at fx = 2000 px.
_RESIDUAL_TOL = 1e-12


def pixel_rays(camera: Camera, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit world-frame directions of the lines of sight of pixels.

    Parameters
    ----------
    camera : Camera
    q : ndarray of shape (N, 2)
        Pixels ``(u, v)``.

    Returns
    -------
    origin : ndarray of shape (3,)
        The optical centre, world metres.
    dirs : ndarray of shape (N, 3)
        Unit directions, world frame; NaN where the distortion cannot be inverted.
    """
    import cv2

    q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
    d_full = distortion.pad_coefficients(camera.params[4:])
    xy_d = (q - camera.params[2:4]) / camera.params[:2]
    if camera.model == "pinhole":
        xy = xy_d
    else:
        K, dist, _, _ = camera.to_opencv()
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-15)
        xy = cv2.undistortPoints(q.reshape(-1, 1, 2), K, dist, criteria=criteria).reshape(-1, 2)
        resid = np.abs(distortion.distort(xy, d_full) - xy_d).max(axis=1)
        slow = ~(resid < _RESIDUAL_TOL)
        if np.any(slow):
            xy[slow] = camera.unproject(q[slow])[0]
    d_cam = np.column_stack([xy, np.ones(len(xy))])
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    world_from_cam = camera.cam_from_world.inverse()
    return world_from_cam.t.copy(), d_cam @ world_from_cam.R.T


class PixelRayTable:
    """Lines of sight of a camera's pixel centres, solved once, interpolated at sub-pixel positions.

    The undistortion map is smooth: bilinear interpolation between pixel centres errs by at
    most ``h² / 8`` times its second derivative, about 1e-4 px at the extreme corners of a
    strongly distorting lens (k1 = -0.35) and far less elsewhere, so sub-pixel samples cost no solve at all.

    Parameters
    ----------
    camera : Camera
    """

    def __init__(self, camera: Camera):
        self.camera = camera
        world_from_cam = camera.cam_from_world.inverse()
        self.origin = world_from_cam.t.copy()
        self._R = world_from_cam.R

    @cached_property
    def xy(self) -> np.ndarray:
        """Undistorted normalised coordinates of every pixel centre, shape (H, W, 2)."""
        cam = self.camera
        u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
        _, dirs = pixel_rays(cam, np.column_stack([u.ravel(), v.ravel()]))
        d_cam = dirs @ self._R
        return (d_cam[:, :2] / d_cam[:, 2:]).reshape(cam.height, cam.width, 2)

    def grid_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Rays of all pixel centres in row-major order: origin (3,), dirs (H*W, 3)."""
        return self._to_world(self.xy.reshape(-1, 2))

    def rays(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Like :func:`pixel_rays` for pixels ``q`` (N, 2) inside the image (clamped to its edge)."""
        xy = self.xy
        h, w = xy.shape[:2]
        u = np.clip(q[:, 0], 0.0, w - 1.0)
        v = np.clip(q[:, 1], 0.0, h - 1.0)
        u0 = np.minimum(np.floor(u).astype(np.int64), w - 2)
        v0 = np.minimum(np.floor(v).astype(np.int64), h - 2)
        fu, fv = (u - u0)[:, None], (v - v0)[:, None]
        # extrapolate linearly past the outermost centres (half a pixel at most)
        fu += (q[:, 0:1] - u[:, None])
        fv += (q[:, 1:2] - v[:, None])
        top = xy[v0, u0] * (1 - fu) + xy[v0, u0 + 1] * fu
        bottom = xy[v0 + 1, u0] * (1 - fu) + xy[v0 + 1, u0 + 1] * fu
        return self._to_world(top * (1 - fv) + bottom * fv)

    def _to_world(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d_cam = np.empty((len(xy), 3))
        d_cam[:, :2] = xy
        d_cam[:, 2] = 1.0
        d_cam /= np.sqrt(np.einsum("ij,ij->i", d_cam, d_cam))[:, None]
        return self.origin, d_cam @ self._R.T
