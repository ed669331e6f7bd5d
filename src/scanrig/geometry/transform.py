"""Rigid transforms named ``b_from_a``: they map points from frame a into frame b.

``cam_from_world`` is exactly what OpenCV's ``rvec, tvec`` mean; chains read naturally::

    cam_from_target = cam_from_world @ world_from_target
    p_cam = cam_from_target.apply(p_target)          # (N, 3) -> (N, 3)

Rotations act on column vectors; with row points that is ``p @ R.T + t``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from scanrig.errors import ShapeError
from scanrig.geometry.checks import check_matrix, check_points

#: Largest deviation of R @ R.T from the identity accepted as a rotation (float64 round-off of
#: a matrix that went through a text file or a few compositions stays orders of magnitude below).
ORTHONORMAL_TOL = 1e-9


@dataclass(frozen=True)
class RigidTransform:
    """A rotation followed by a translation: ``p_b = R @ p_a + t``.

    Parameters
    ----------
    R : array_like of shape (3, 3)
        Proper rotation matrix (orthonormal, determinant +1).
    t : array_like of shape (3,)
        Translation in metres, expressed in the destination frame.
    """

    R: np.ndarray
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        R = check_matrix(self.R, (3, 3), "R")
        t = check_matrix(self.t, (3,), "t")
        if np.abs(R @ R.T - np.eye(3)).max() > ORTHONORMAL_TOL or np.linalg.det(R) < 0:
            raise ShapeError(f"R must be a proper rotation matrix (orthonormal, det +1), got {R.tolist()}")
        R.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    @classmethod
    def identity(cls) -> RigidTransform:
        """The transform that leaves every point where it is."""
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_rvec_tvec(cls, rvec, tvec) -> RigidTransform:
        """Build from a Rodrigues rotation vector (radians) and a translation, as OpenCV does."""
        rvec = check_matrix(np.ravel(rvec), (3,), "rvec")
        return cls(Rotation.from_rotvec(rvec).as_matrix(), np.ravel(tvec))

    @classmethod
    def from_matrix(cls, matrix) -> RigidTransform:
        """Build from a homogeneous ``(4, 4)`` matrix whose last row is ``[0, 0, 0, 1]``."""
        m = check_matrix(matrix, (4, 4), "matrix")
        if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
            raise ShapeError(f"matrix must have last row [0, 0, 0, 1], got {m[3].tolist()}")
        return cls(m[:3, :3], m[:3, 3])

    @property
    def rvec(self) -> np.ndarray:
        """Rodrigues rotation vector, shape (3,), radians."""
        return Rotation.from_matrix(self.R).as_rotvec()

    @property
    def tvec(self) -> np.ndarray:
        """Translation, shape (3,), metres (a copy)."""
        return self.t.copy()

    def as_matrix(self) -> np.ndarray:
        """Homogeneous ``(4, 4)`` matrix."""
        m = np.eye(4)
        m[:3, :3] = self.R
        m[:3, 3] = self.t
        return m

    def apply(self, points) -> np.ndarray:
        """Map points ``(N, 3)`` from the source frame into the destination frame."""
        p = check_points(points, 3, "points")
        return p @ self.R.T + self.t

    def inverse(self) -> RigidTransform:
        """The transform ``a_from_b`` of this ``b_from_a``."""
        return RigidTransform(self.R.T, -self.R.T @ self.t)

    def __matmul__(self, other: RigidTransform) -> RigidTransform:
        if not isinstance(other, RigidTransform):
            return NotImplemented
        return RigidTransform(self.R @ other.R, self.R @ other.t + self.t)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]_x`` of shape ``(..., 3, 3)`` for vectors ``(..., 3)``."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def canonical_rvec_jacobian(rvec: np.ndarray) -> np.ndarray:
    """Derivative of the canonical rotation vector of ``R(rvec)`` with respect to ``rvec``.

    The canonical vector (angle at most π) is what :attr:`RigidTransform.rvec` returns, and what
    Jacobians computed from a transform are taken with respect to. An optimiser's rotation vector
    may grow past π; the same rotation is then ``rvec (1 − 2πk/θ)``, ``θ = |rvec|``,
    ``k = round(θ / 2π)``, and a Jacobian by the canonical vector times this one is the Jacobian by
    ``rvec``.

    Parameters
    ----------
    rvec : ndarray of shape (3,)
        Rotation vector, radians.

    Returns
    -------
    ndarray of shape (3, 3)
        ``J[i, j] = d canonical_i / d rvec_j``: the identity for angles up to π.
    """
    theta = float(np.linalg.norm(rvec))
    turns = round(theta / (2.0 * np.pi))
    if turns == 0:
        return np.eye(3)
    wrap = 2.0 * np.pi * turns / theta
    return (1.0 - wrap) * np.eye(3) + wrap / theta**2 * np.outer(rvec, rvec)


def rotated_point_jacobian_rvec(rvec: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Derivative of ``R(rvec) @ p`` with respect to the rotation vector.

    Uses the closed form of Gallego & Yezzi (2015), "A compact formula for the derivative of a
    3-D rotation in exponential coordinates": ``d(Rp)/dv = -R [p]_x (v v^T + (R^T - I)[v]_x) / |v|^2``,
    which tends to ``-[p]_x`` as ``|v| -> 0``.

    Parameters
    ----------
    rvec : ndarray of shape (3,)
        Rotation vector, radians.
    p : ndarray of shape (N, 3)
        Points before rotation.

    Returns
    -------
    ndarray of shape (N, 3, 3)
        ``J[n, i, j] = d (R p_n)_i / d rvec_j``.
    """
    theta2 = float(rvec @ rvec)
    if theta2 < 1e-24:
        return -skew(p)
    R = Rotation.from_rotvec(rvec).as_matrix()
    M = (np.outer(rvec, rvec) + (R.T - np.eye(3)) @ skew(rvec)) / theta2
    return -np.einsum("ij,njk,kl->nil", R, skew(p), M, optimize=True)
