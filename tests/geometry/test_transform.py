"""RigidTransform: composition, inversion, conversions, validation."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanrig.errors import ShapeError
from scanrig.geometry import RigidTransform
from scanrig.geometry.transform import canonical_rvec_jacobian, rotated_point_jacobian_rvec

#: Float64 round-off after a few 3x3 products and a rotation-vector conversion.
ROUNDOFF = 1e-12

vec3 = st.lists(st.floats(-3, 3), min_size=3, max_size=3).map(np.array)


@settings(max_examples=200, deadline=None)
@given(r1=vec3, t1=vec3, r2=vec3, t2=vec3)
def test_composition_and_inverse(r1, t1, r2, t2):
    a = RigidTransform.from_rvec_tvec(r1, t1)
    b = RigidTransform.from_rvec_tvec(r2, t2)
    p = np.array([[0.1, -0.2, 0.3], [1.0, 2.0, 3.0]])
    np.testing.assert_allclose((a @ b).apply(p), a.apply(b.apply(p)), atol=ROUNDOFF * 10)
    np.testing.assert_allclose((a @ a.inverse()).as_matrix(), np.eye(4), atol=ROUNDOFF)
    np.testing.assert_allclose(RigidTransform.from_matrix(a.as_matrix()).as_matrix(), a.as_matrix(), atol=0)
    again = RigidTransform.from_rvec_tvec(a.rvec, a.tvec)
    np.testing.assert_allclose(again.R, a.R, atol=ROUNDOFF)


def test_rotation_jacobian_matches_differences_including_zero_angle():
    rng = np.random.default_rng(3)
    p = rng.normal(size=(5, 3))
    for rvec in (np.zeros(3), np.array([1e-9, 0, 0]), rng.normal(size=3)):
        J = rotated_point_jacobian_rvec(rvec, p)
        h = 1e-6
        num = np.stack(
            [(RigidTransform.from_rvec_tvec(rvec + h * e, np.zeros(3)).apply(p)
              - RigidTransform.from_rvec_tvec(rvec - h * e, np.zeros(3)).apply(p)) / (2 * h) for e in np.eye(3)],
            axis=-1,
        )
        np.testing.assert_allclose(J, num, atol=1e-8)


@pytest.mark.parametrize(
    "R,t,message",
    [
        (np.eye(3) * 2, np.zeros(3), "R must be a proper rotation"),
        (np.diag([1.0, 1.0, -1.0]), np.zeros(3), "R must be a proper rotation"),
        (np.eye(2), np.zeros(3), r"R must have shape \(3, 3\), got \(2, 2\)"),
        (np.eye(3), np.zeros(4), r"t must have shape \(3,\), got \(4,\)"),
        (np.eye(3), [0, np.inf, 0], "t must be finite"),
    ],
)
def test_bad_transforms_raise(R, t, message):
    with pytest.raises(ShapeError, match=message):
        RigidTransform(R, t)


def test_transform_is_immutable():
    a = RigidTransform.identity()
    with pytest.raises(ValueError):
        a.R[0, 0] = 2.0


@pytest.mark.parametrize("angle", [0.3, 2.0, 3.0, 3.3, 5.0, 7.0, 9.0])
def test_canonical_rvec_jacobian_matches_finite_differences(angle):
    """The derivative of the canonical rotation vector (angle ≤ π) by a rotation vector of any
    angle: the identity up to π, a different matrix past it."""
    rvec = angle * np.array([0.48, -0.6, 0.64])
    step = 1e-6
    numeric = np.column_stack([(RigidTransform.from_rvec_tvec(rvec + d, np.zeros(3)).rvec
                                - RigidTransform.from_rvec_tvec(rvec - d, np.zeros(3)).rvec) / (2 * step)
                               for d in step * np.eye(3)])
    np.testing.assert_allclose(canonical_rvec_jacobian(rvec), numeric, atol=1e-7)
