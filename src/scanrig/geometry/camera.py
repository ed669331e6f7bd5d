"""The camera model: a pose, pinhole intrinsics and OpenCV's Brown–Conrady distortion.

Projection is three steps (see ``docs/conventions.md``)::

    p_cam = cam_from_world.apply(p_world)        # world -> camera frame (x right, y down, z forward)
    xy    = p_cam[:, :2] / p_cam[:, 2:]          # normalise by depth
    q     = [fx, fy] * distort(xy) + [cx, cy]    # distort, then apply intrinsics (pixels)

Pixel (0, 0) is the centre of the top-left pixel, as in OpenCV and mrcal.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry import distortion
from scanrig.geometry.checks import check_matrix, check_points, check_positive_int
from scanrig.geometry.transform import RigidTransform, rotated_point_jacobian_rvec

#: Intrinsic parameter names that precede the distortion coefficients in ``Camera.params``.
PINHOLE_PARAMS = ("fx", "fy", "cx", "cy")


@dataclass(frozen=True)
class Camera:
    """One calibrated camera.

    Parameters
    ----------
    name : str
        Unique name within a rig (the session's camera folder name).
    model : str
        ``"pinhole"``, ``"opencv4"``, ``"opencv5"``, ``"opencv8"`` or ``"opencv12"``.
    params : array_like of shape (4 + n_dist,)
        ``fx fy cx cy`` in pixels, then the model's distortion coefficients in OpenCV order
        (``k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4``, truncated to the model).
    width, height : int
        Image size in pixels.
    cam_from_world : RigidTransform
        Pose: maps world points into this camera's frame.
    """

    name: str
    model: str
    params: np.ndarray
    width: int
    height: int
    cam_from_world: RigidTransform = field(default_factory=RigidTransform.identity)

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"camera name must be a non-empty string, got {self.name!r}")
        if self.model not in distortion.MODEL_COEFFICIENTS:
            raise InputError(
                f"camera {self.name!r}: model must be one of "
                f"{sorted(distortion.MODEL_COEFFICIENTS)}, got {self.model!r}"
            )
        n_params = len(PINHOLE_PARAMS) + len(distortion.MODEL_COEFFICIENTS[self.model])
        params = check_matrix(self.params, (n_params,), f"camera {self.name!r} params ({self.model})")
        if params[0] <= 0 or params[1] <= 0:
            raise InputError(f"camera {self.name!r}: fx and fy must be positive, got {params[:2].tolist()}")
        params.setflags(write=False)
        object.__setattr__(self, "params", params)
        object.__setattr__(self, "width", check_positive_int(self.width, f"camera {self.name!r} width"))
        object.__setattr__(self, "height", check_positive_int(self.height, f"camera {self.name!r} height"))
        if not isinstance(self.cam_from_world, RigidTransform):
            raise InputError(f"camera {self.name!r}: cam_from_world must be a RigidTransform")
        object.__setattr__(self, "_dist_full", distortion.pad_coefficients(params[4:]))

    # --- parameter access -------------------------------------------------------------------
    @property
    def param_names(self) -> tuple[str, ...]:
        """Names of ``params`` in order."""
        return PINHOLE_PARAMS + distortion.MODEL_COEFFICIENTS[self.model]

    @property
    def K(self) -> np.ndarray:
        """Camera matrix ``(3, 3)`` (zero skew)."""
        fx, fy, cx, cy = self.params[:4]
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    @property
    def dist(self) -> np.ndarray:
        """Distortion coefficients ``(n_dist,)`` in OpenCV order (a copy)."""
        return self.params[4:].copy()

    @property
    def center_world(self) -> np.ndarray:
        """Optical centre in world coordinates, shape (3,), metres."""
        return self.cam_from_world.inverse().t.copy()

    def with_pose(self, cam_from_world: RigidTransform) -> Camera:
        """A copy of this camera at another pose."""
        return replace(self, cam_from_world=cam_from_world)

    def with_params(self, params) -> Camera:
        """A copy of this camera with other intrinsic parameters (same model)."""
        return replace(self, params=np.asarray(params, dtype=np.float64))

    # --- OpenCV interchange -------------------------------------------------------------------
    @classmethod
    def from_opencv(cls, name: str, K, dist, R, t, width: int, height: int) -> Camera:
        """Build from OpenCV's camera matrix, distortion vector and pose.

        Parameters
        ----------
        name : str
            Camera name.
        K : array_like of shape (3, 3)
            Camera matrix; skew must be zero.
        dist : array_like of 0, 4, 5, 8 or 12 coefficients
            OpenCV distortion vector; its length selects the model.
        R : array_like of shape (3, 3) or (3,)
            Rotation ``cam_from_world`` as a matrix or a Rodrigues vector (OpenCV's rvec).
        t : array_like of shape (3,)
            Translation ``cam_from_world`` (OpenCV's tvec), metres.
        width, height : int
            Image size in pixels.
        """
        K = check_matrix(K, (3, 3), "K")
        if K[0, 1] != 0.0 or K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0 or K[2, 2] != 1.0:
            raise InputError(f"K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (zero skew), got {K.tolist()}")
        dist = np.ravel(np.asarray(dist, dtype=np.float64))
        model = distortion.model_from_n_coefficients(dist.size)
        R = np.asarray(R, dtype=np.float64)
        if R.size == 3:
            pose = RigidTransform.from_rvec_tvec(R, np.ravel(t))
        else:
            pose = RigidTransform(R, np.ravel(t))
        params = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dist])
        return cls(name, model, params, width, height, pose)

    def to_opencv(self):
        """Return ``(K (3,3), dist (n,), R (3,3), t (3,))`` for OpenCV functions."""
        return self.K, self.dist, self.cam_from_world.R.copy(), self.cam_from_world.t.copy()

    # --- projection ---------------------------------------------------------------------------
    def project(self, p_world) -> np.ndarray:
        """Project world points to pixels.

        Parameters
        ----------
        p_world : array_like of shape (N, 3)
            Points in the world frame, metres.

        Returns
        -------
        ndarray of shape (N, 2)
            Pixels ``(u, v)``; NaN for points on or behind the camera's image plane (z <= 0).
        """
        p = check_points(p_world, 3, "p_world")
        pose = self.cam_from_world
        p_cam = p @ pose.R.T + pose.t
        return self._project_cam(p_cam)

    def project_cam(self, p_cam) -> np.ndarray:
        """Project points already in the camera frame, ``(N, 3) -> (N, 2)`` pixels."""
        return self._project_cam(check_points(p_cam, 3, "p_cam"))

    def _project_cam(self, p_cam: np.ndarray) -> np.ndarray:
        z = p_cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p_cam[:, :2] / z[:, None]
        xy_d = distortion.distort(xy, self._dist_full)
        q = xy_d * self.params[:2] + self.params[2:4]
        q[z <= 0.0] = np.nan
        return q

    def project_with_point_jacobian(self, p_world):
        """Project points and return only ``dq / dp_world``, the cheap Jacobian triangulation needs.

        Returns
        -------
        q : ndarray of shape (N, 2)
            Pixels, NaN behind the camera.
        J_point : ndarray of shape (N, 2, 3)
            ``dq / dp_world``, NaN behind the camera.
        """
        p = check_points(p_world, 3, "p_world")
        q, J_q_pcam, _, _ = self._project_parts(p, with_coefficients=False)
        J_point = J_q_pcam @ self.cam_from_world.R
        J_point[np.isnan(q[:, 0])] = np.nan
        return q, J_point

    def project_with_jacobians(self, p_world):
        """Project points and return the analytic Jacobians of the pixels.

        Parameters
        ----------
        p_world : array_like of shape (N, 3)
            Points in the world frame.

        Returns
        -------
        q : ndarray of shape (N, 2)
            Pixels, NaN behind the camera.
        J_point : ndarray of shape (N, 2, 3)
            ``dq / dp_world``.
        J_pose : ndarray of shape (N, 2, 6)
            ``dq / d(rvec, tvec)`` of ``cam_from_world`` (OpenCV's pose parameters).
        J_intrinsics : ndarray of shape (N, 2, len(params))
            ``dq / dparams`` in the order of :attr:`param_names`.
        """
        p = check_points(p_world, 3, "p_world")
        pose = self.cam_from_world
        q, J_q_pcam, xy_d, J_dist_coeffs = self._project_parts(p, with_coefficients=True)
        f = self.params[:2]
        J_point = J_q_pcam @ pose.R
        J_rot = rotated_point_jacobian_rvec(pose.rvec, p)
        J_pose = np.concatenate([np.einsum("nij,njk->nik", J_q_pcam, J_rot), J_q_pcam], axis=2)

        n_dist = len(self.params) - 4
        J_intr = np.zeros((p.shape[0], 2, 4 + n_dist))
        J_intr[:, 0, 0] = xy_d[:, 0]
        J_intr[:, 1, 1] = xy_d[:, 1]
        J_intr[:, 0, 2] = 1.0
        J_intr[:, 1, 3] = 1.0
        J_intr[:, :, 4:] = f[None, :, None] * J_dist_coeffs[:, :, :n_dist]

        behind = np.isnan(q[:, 0])
        for arr in (J_point, J_pose, J_intr):
            arr[behind] = np.nan
        return q, J_point, J_pose, J_intr

    def _project_parts(self, p: np.ndarray, with_coefficients: bool):
        """Pixels ``(N, 2)`` (NaN behind), ``dq/dp_cam`` ``(N, 2, 3)``, distorted coordinates and,
        if asked, the distortion's coefficient Jacobian ``(N, 2, 12)`` (else None)."""
        pose = self.cam_from_world
        p_cam = p @ pose.R.T + pose.t
        x, y, z = p_cam[:, 0], p_cam[:, 1], p_cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_z = 1.0 / z
            xy = p_cam[:, :2] * inv_z[:, None]
        if with_coefficients:
            xy_d, J_dist_xy, J_dist_coeffs = distortion.distort_with_jacobians(xy, self._dist_full)
        else:
            (xy_d, J_dist_xy), J_dist_coeffs = distortion.distort_with_point_jacobian(xy, self._dist_full), None
        f = self.params[:2]
        q = xy_d * f + self.params[2:4]
        # dq/dp_cam = diag(f) · J_dist · d(x/z, y/z)/dp_cam, written out for the 2x3 product.
        J_q_pcam = np.empty((p.shape[0], 2, 3))
        for row in range(2):
            a, b = J_dist_xy[:, row, 0] * f[row], J_dist_xy[:, row, 1] * f[row]
            J_q_pcam[:, row, 0] = a * inv_z
            J_q_pcam[:, row, 1] = b * inv_z
            J_q_pcam[:, row, 2] = -(a * x + b * y) * inv_z * inv_z
        q[z <= 0.0] = np.nan
        return q, J_q_pcam, xy_d, J_dist_coeffs

    # --- back-projection ----------------------------------------------------------------------
    def unproject(self, q):
        """Undistorted normalised coordinates of pixels, by an iterative Newton solve.

        Parameters
        ----------
        q : array_like of shape (N, 2)
            Pixels ``(u, v)``.

        Returns
        -------
        xy : ndarray of shape (N, 2)
            ``(X/Z, Y/Z)`` in the camera frame; NaN where the solve did not converge.
        converged : ndarray of shape (N,), bool
            False where the model cannot be inverted at that pixel (beyond a fold of the
            distortion, or non-finite input).
        """
        q = check_points(q, 2, "q")
        x, y, converged = distortion.undistort_components(
            q[:, 0], q[:, 1], self._dist_full, scale=tuple(float(c) for c in self.params[:4]))
        xy = np.empty((x.shape[0], 2))
        xy[:, 0], xy[:, 1] = x, y
        return xy, converged

    def rays(self, q):
        """Lines of sight of pixels, in the world frame.

        Parameters
        ----------
        q : array_like of shape (N, 2)
            Pixels ``(u, v)``.

        Returns
        -------
        origins : ndarray of shape (N, 3)
            The optical centre (world), repeated per pixel.
        dirs : ndarray of shape (N, 3)
            Unit directions (world); NaN where :meth:`unproject` did not converge.
        """
        q = check_points(q, 2, "q")
        dirs = np.empty((q.shape[0], 3))
        self.ray_directions(q[:, 0], q[:, 1], dirs[:, 0], dirs[:, 1], dirs[:, 2])
        origins = np.broadcast_to(self.center_world, dirs.shape).copy()
        return origins, dirs

    def ray_directions(self, u: np.ndarray, v: np.ndarray, out_x: np.ndarray, out_y: np.ndarray,
                       out_z: np.ndarray) -> None:
        """World unit directions of the pixels ``(u, v)``, written component by component.

        The array form of :meth:`rays` for callers that keep coordinates as separate arrays
        (triangulation): ``u, v`` are ``(N,)`` float arrays of any strides, and the three
        ``(N,)`` outputs receive the x, y and z components (NaN where :meth:`unproject` did not
        converge, including non-finite pixels).
        """
        x, y, _ = distortion.undistort_components(
            u, v, self._dist_full, scale=tuple(float(c) for c in self.params[:4]))
        R = self.cam_from_world.R.T  # world_from_cam rotation
        n = x.shape[0]
        # d_world = R_wc [x, y, 1] / |[x, y, 1]|, on cache-sized blocks of the coordinate arrays.
        block = min(max(n, 1), distortion.UNDISTORT_BLOCK)
        inv_buf, t_buf, u_buf = np.empty(block), np.empty(block), np.empty(block)
        outs = (out_x, out_y, out_z)
        for start in range(0, n, block):
            s = slice(start, min(start + block, n))
            m = s.stop - start
            xb, yb, inv, t, w = x[s], y[s], inv_buf[:m], t_buf[:m], u_buf[:m]
            np.multiply(xb, xb, out=inv)
            np.multiply(yb, yb, out=t)
            inv += t
            inv += 1.0
            np.sqrt(inv, out=inv)
            np.divide(1.0, inv, out=inv)
            xb *= inv
            yb *= inv
            for k in range(3):
                o = outs[k][s]
                np.multiply(xb, R[k, 0], out=o)
                np.multiply(yb, R[k, 1], out=w)
                o += w
                np.multiply(inv, R[k, 2], out=w)
                o += w
