"""Covariance propagation and the batched symmetric 3×3 helpers."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanrig.errors import InputError, ShapeError
from scanrig.geometry.triangulation import triangulate
from scanrig.geometry.uncertainty import (
    information_matrix,
    inv_sym3,
    max_eigenvalue_sym3,
    point_covariance,
    sigma_from_covariance,
)
from tests.reconstruct.synth import WIDTH, observe, points_in_cube, ring_rig

#: Closed forms against LAPACK: relative round-off of a few hundred ulps on well-conditioned input.
CLOSED_FORM_RTOL = 1e-9
#: Monte-Carlo check: 4000 draws estimate each covariance entry to ~sqrt(2/4000) = 2.2 % (1 σ);
#: 10 % is over four standard errors.
MONTE_CARLO_RTOL = 0.10


def _random_spd(rng, n, spread=1e3):
    Q = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    eig = np.exp(rng.uniform(0.0, np.log(spread), (n, 3)))
    return np.einsum("nij,nj,nkj->nik", Q, eig, Q)


def test_inverse_matches_lapack():
    A = _random_spd(np.random.default_rng(21), 500)
    inv, singular = inv_sym3(A)
    assert not singular.any()
    np.testing.assert_allclose(inv, np.linalg.inv(A), rtol=CLOSED_FORM_RTOL, atol=0)


def test_singular_matrices_give_nan():
    A = np.zeros((2, 3, 3))
    A[0] = np.diag([1.0, 1.0, 0.0])
    A[1] = np.eye(3)
    inv, singular = inv_sym3(A)
    assert singular.tolist() == [True, False]
    assert np.isnan(inv[0]).all() and np.allclose(inv[1], np.eye(3))


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), repeated=st.sampled_from([0, 2, 3]))
def test_largest_eigenvalue_matches_lapack(seed, repeated):
    rng = np.random.default_rng(seed)
    A = _random_spd(rng, 50)
    if repeated:  # equal eigenvalues are the closed form's delicate case
        Q = np.linalg.qr(rng.normal(size=(50, 3, 3)))[0]
        eig = np.sort(rng.uniform(0.1, 10.0, (50, 3)), axis=1)
        eig[:, 3 - repeated:] = eig[:, -1:]
        A = np.einsum("nij,nj,nkj->nik", Q, eig, Q)
    expected = np.linalg.eigvalsh(A)[:, -1]
    # Near-repeated eigenvalues make arccos ill-conditioned: the error grows like sqrt(eps).
    np.testing.assert_allclose(max_eigenvalue_sym3(A), expected, rtol=1e-7)


def test_sigma_is_the_largest_axis():
    cov = np.diag([4e-8, 1e-8, 9e-8])[None]
    assert sigma_from_covariance(cov)[0] == pytest.approx(3e-4, rel=CLOSED_FORM_RTOL)


def test_information_matrix_matches_einsum():
    rng = np.random.default_rng(22)
    J = rng.normal(size=(3, 40, 2, 3))
    W = np.linalg.inv(np.einsum("cnij,cnkj->cnik", *(2 * [rng.normal(size=(3, 40, 2, 2))])) + np.eye(2))
    used = rng.random((3, 40)) > 0.3
    J[~used] = np.nan
    expected = np.einsum("cn,cnji,cnjk,cnkl->nil", used, np.nan_to_num(J), W, np.nan_to_num(J))
    np.testing.assert_allclose(information_matrix(J, W, used), expected, rtol=CLOSED_FORM_RTOL, atol=1e-12)


def test_point_covariance_matches_monte_carlo():
    """Repeated noisy observations of fixed points scatter as the predicted covariance says."""
    rng = np.random.default_rng(23)
    rig = ring_rig()
    p_true = points_in_cube(rng, 3)
    predicted = point_covariance(rig.cameras, p_true, sigma_px=0.4)
    draws = 4000
    p_rep = np.repeat(p_true, draws, axis=0)
    p_hat, _ = triangulate(rig, observe(rig, p_rep, rng, 0.4), sigma_px=0.4)
    for k in range(3):
        sample = np.cov((p_hat[k * draws:(k + 1) * draws]).T)
        scale = np.sqrt(np.outer(np.diag(predicted[k]), np.diag(predicted[k])))
        assert np.abs(sample - predicted[k]).max() < MONTE_CARLO_RTOL * scale.max()


def test_point_covariance_counts_only_cameras_that_see_the_point():
    rig = ring_rig()
    cam0 = rig.cameras[0]
    # A point far to the side of camera 0's image: in front of all cameras but outside cam0's view.
    corner = cam0.cam_from_world.inverse().apply(np.array([[2.0 * WIDTH / 2400, 0.0, 1.0]]))
    inside = np.zeros((1, 3))
    cov = point_covariance(rig.cameras, np.vstack([inside, corner]), sigma_px=1.0)
    only12 = point_covariance(rig.cameras[1:], inside, sigma_px=1.0)
    assert np.isfinite(cov[0]).all()
    assert cam0.project(corner)[0, 0] > WIDTH  # outside camera 0, so only cameras 1 and 2 count
    np.testing.assert_allclose(cov[1], point_covariance(rig.cameras[1:], corner, 1.0)[0], rtol=1e-12)
    assert np.trace(cov[0]) < np.trace(only12[0])  # a third view helps
    visible = np.array([[False], [True], [True]])
    np.testing.assert_allclose(point_covariance(rig.cameras, inside, 1.0, visible), only12, rtol=1e-12)
    single = point_covariance(rig.cameras[:1], inside, sigma_px=1.0)
    assert np.isnan(single).all()


def test_point_covariance_bad_input():
    rig = ring_rig()
    with pytest.raises(ShapeError, match=r"sigma_px must be a scalar or have shape \(3, 2\), got \(2,\)"):
        point_covariance(rig.cameras, np.zeros((2, 3)), sigma_px=np.ones(2))
    with pytest.raises(ShapeError, match=r"visible must have shape \(3, 2\), got \(2,\)"):
        point_covariance(rig.cameras, np.zeros((2, 3)), visible=np.ones(2, bool))
    with pytest.raises(ShapeError, match=r"p_world must have shape \(N, 3\), got \(3,\)"):
        point_covariance(rig.cameras, np.zeros(3))
    with pytest.raises(InputError, match="cameras must contain at least one Camera"):
        point_covariance([], np.zeros((2, 3)))
