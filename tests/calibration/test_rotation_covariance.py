"""The rotation-error covariance is the Rodrigues covariance mapped through the exact derivative."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from scanrig.calibration.uncertainty import rotation_error_covariance

ANGLE = st.floats(0.0, 3.0)
AXIS = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda a: np.linalg.norm(a) > 0.1)


@settings(max_examples=50, deadline=None)
@given(angle=ANGLE, axis=AXIS, seed=st.integers(0, 2**31 - 1))
def test_matches_the_error_rotation_of_small_rodrigues_steps(angle, axis, seed):
    rvec = np.asarray(axis) / np.linalg.norm(axis) * angle
    rng = np.random.default_rng(seed)
    step = 1e-6
    drs = rng.normal(scale=step, size=(400, 3))
    R = Rotation.from_rotvec(rvec)
    errors = np.array([(Rotation.from_rotvec(rvec + dr) * R.inv()).as_rotvec() for dr in drs])
    # Linear map from dr to the error vector, fitted from the steps; the covariance of an isotropic
    # dr then has to equal A Aᵀ step².
    A = np.linalg.lstsq(drs, errors, rcond=None)[0].T
    expected = A @ A.T * step**2
    np.testing.assert_allclose(rotation_error_covariance(rvec, np.eye(3) * step**2), expected,
                               rtol=1e-4, atol=1e-6 * step**2)


def test_identity_rotation_keeps_the_rodrigues_covariance():
    cov = np.diag([1.0, 2.0, 3.0]) * 1e-8
    np.testing.assert_allclose(rotation_error_covariance(np.zeros(3), cov), cov, rtol=1e-12)
