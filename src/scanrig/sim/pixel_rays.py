"""Lines of sight of many pixels, fast.

``Camera.rays`` is general and exact; a simulator casts millions of camera rays per image. Here
every pixel is solved once by the camera's own vectorised undistortion (:meth:`Camera.unproject`:
Newton's method to a residual below 1e-12 in normalised units, with the fold check), and a
:class:`PixelRayTable` interpolates between pixel centres for sub-pixel rays.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

from scanrig.geometry import Camera


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
    q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
    world_from_cam = camera.cam_from_world.inverse()
    return world_from_cam.t.copy(), _to_world(_normalised(camera, q), world_from_cam.R)


def _normalised(camera: Camera, q: np.ndarray) -> np.ndarray:
    """Undistorted normalised coordinates ``(X/Z, Y/Z)`` of pixels (N, 2); NaN where not invertible."""
    if camera.model == "pinhole":
        return (q - camera.params[2:4]) / camera.params[:2]
    return camera.unproject(q)[0]


def _to_world(xy: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Unit world directions of normalised camera coordinates ``xy`` (N, 2); ``R`` is world_from_cam.

    The additions and divisions run column by column: broadcasting a (3,) row or an (N, 1)
    column over (N, 3) ran an inner loop per ray (1.2 vs 2.1 ms per 32 768 rays).
    """
    d = xy @ R[:, :2].T                  # R @ (x, y, 1)
    x, y = xy[:, 0], xy[:, 1]
    norm = x * x                         # |(x, y, 1)|, summed in einsum's order: x², + y², + 1
    norm += y * y
    norm += 1.0
    np.sqrt(norm, out=norm)
    for axis in range(3):
        column = d[:, axis]
        column += R[axis, 2]
        column /= norm
    return d


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
        return _normalised(cam, np.column_stack([u.ravel(), v.ravel()])).reshape(cam.height, cam.width, 2)

    def grid_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Rays of all pixel centres in row-major order: origin (3,), dirs (H*W, 3)."""
        return self.origin, self.to_world(self.xy.reshape(-1, 2))

    @cached_property
    def _xy_planes(self) -> np.ndarray:
        """:attr:`xy` as two planes, x then y, each of the pixels in row-major order: (2, H*W)."""
        return np.ascontiguousarray(np.moveaxis(self.xy, 2, 0).reshape(2, -1))

    def rays(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Like :func:`pixel_rays` for pixels ``q`` (N, 2) inside the image (clamped to its edge)."""
        return self.rays_uv(q[:, 0], q[:, 1])

    def rays_uv(self, u_px: np.ndarray, v_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`rays` of the pixels ``(u_px, v_px)``, each of shape (N,): origin (3,), dirs (N, 3).

        Each normalised coordinate is interpolated on its own plane of :attr:`xy`: the gathers and
        products then run over whole arrays, not over (x, y) pairs (an inner loop per pair).
        """
        h, w = self.xy.shape[:2]
        u0 = np.minimum(np.clip(u_px, 0.0, w - 1.0).astype(np.int64), w - 2)    # floor: clipped >= 0
        v0 = np.minimum(np.clip(v_px, 0.0, h - 1.0).astype(np.int64), h - 2)
        # extrapolate linearly past the outermost centres (half a pixel at most)
        fu = u_px - u0
        fv = v_px - v0
        i00 = v0 * w
        i00 += u0
        i10 = i00 + w
        xy = np.empty((len(u_px), 2))
        for axis, plane in enumerate(self._xy_planes):
            top = self._lerp(plane, i00, fu)
            bottom = self._lerp(plane, i10, fu)
            bottom -= top
            bottom *= fv
            np.add(top, bottom, out=xy[:, axis])
        return self.origin, self.to_world(xy)

    @staticmethod
    def _lerp(plane: np.ndarray, i0: np.ndarray, f: np.ndarray) -> np.ndarray:
        """``plane[i0] + (plane[i0 + 1] - plane[i0]) f``, each (N,), in that order of operations."""
        low = np.take(plane, i0)
        high = np.take(plane, i0 + 1)
        high -= low
        high *= f
        high += low
        return high

    def to_world(self, xy: np.ndarray) -> np.ndarray:
        """Unit world directions of normalised camera coordinates ``xy`` (N, 2)."""
        return _to_world(xy, self._R)
