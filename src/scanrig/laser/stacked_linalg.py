"""Small symmetric systems, one per candidate, stacked along the last axis.

The laser fits hold one ``P × P`` normal matrix per candidate, ``P`` = 3–8, for a thousand or
more candidates at once. Stored *candidate-minor* (``(P, P, n)``: each entry one contiguous
``(n,)`` row), their Gram matrices, Cholesky factorisations, solves and inverses are written out
entry by entry over the candidate axis: a few NumPy calls per entry on long rows, where LAPACK's
batched routines pay a call per matrix. Below ``_UNROLLED_PER_PARAMETER · P`` candidates the fixed
cost of order P³ NumPy calls no longer pays, and the stacks go to LAPACK instead.
"""

from __future__ import annotations

import functools

import numpy as np


#: Below this many candidates, Gram matrices and leverages are batched matrix products (else
#: contractions over the candidate axis); measured crossovers 16-60 candidates.
MATMUL_MAX = 32


def gram(jac: np.ndarray) -> np.ndarray:
    """``JᵀJ`` ``(P, P, k)`` of the candidate-minor ``jac (P, M, k)``, lower triangle only (the
    upper may be left unset): row ``i`` is one contraction of ``jac[:i + 1]`` with ``jac[i]``, about
    half the work of the full product; below ``MATMUL_MAX`` candidates, one batched product."""
    size, _, k = jac.shape
    if k < MATMUL_MAX:  # few candidates: one batched product beats P contractions
        return np.ascontiguousarray(np.matmul(jac.transpose(2, 0, 1), jac.transpose(2, 1, 0)).transpose(1, 2, 0))
    out = np.empty((size, size, k))
    for i in range(size):
        np.einsum("jmn,mn->jn", jac[: i + 1], jac[i], out=out[i, : i + 1])
    return out


#: The small symmetric systems of ``k`` candidates with ``P`` parameters are solved by a Cholesky
#: factorisation written out entry by entry over the candidate axis (a few NumPy operations per
#: matrix entry, each on all candidates at once: a fixed cost of order P³ operations) from
#: ``k = _UNROLLED_PER_PARAMETER · P`` candidates on; below, LAPACK's per-matrix calls (a cost of
#: order k) are cheaper. Measured crossovers, one core: 80-260 candidates for P = 4-10 (the solve),
#: 50-160 (the inverse).
_UNROLLED_PER_PARAMETER = 20


def _unrolled(n_par: int, k: int) -> bool:
    """Whether ``k`` systems of ``n_par`` parameters are solved by the unrolled factorisation."""
    return k >= _UNROLLED_PER_PARAMETER * n_par


def damped_solve(hess: np.ndarray, grad: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Levenberg–Marquardt step ``(P, k)``: the solution of ``(JᵀJ + λ diag(JᵀJ) + ε) δ = Jᵀr``
    for the normal equations ``hess (P, P, k)`` (lower triangle read) and ``grad (P, k)`` and
    ``lam (k,)``; a new array."""
    n_par, _, k = hess.shape
    diag = hess.reshape(n_par * n_par, k)[:: n_par + 1]  # a view: the diagonals, (P, k)
    damped = diag + (lam * diag + 1e-12 * diag.max(axis=0) + 1e-300)
    if not _unrolled(n_par, k):  # (k, P, P) stacks for LAPACK
        full = _symmetric_stack(hess)
        full.reshape(k, -1)[:, :: n_par + 1] = damped.T
        return np.linalg.solve(full, grad.T[:, :, None])[:, :, 0].T.copy()
    return cholesky_solve(hess, grad, damped)


@functools.lru_cache(maxsize=16)
def _strict_lower(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the entries below the diagonal of a ``size × size`` matrix."""
    return np.tril_indices(size, -1)


def _symmetric_stack(h: np.ndarray) -> np.ndarray:
    """The symmetric matrices ``(k, P, P)`` (a new array) of ``h (P, P, k)``, lower triangle read."""
    full = h.transpose(2, 0, 1).copy()
    row, col = _strict_lower(h.shape[0])
    full[:, col, row] = full[:, row, col]
    return full


def _cholesky(h: np.ndarray, diag: np.ndarray | None = None):
    """Lower Cholesky factors of a stack ``(P, P, n)`` of symmetric matrices (lower triangle read;
    the diagonal from ``diag (P, n)`` when given), as nested lists ``low[i][j]`` (j ≤ i) of
    ``(n,)`` arrays, and the reciprocals of the diagonal. A matrix that is not positive definite
    gets NaN entries."""
    size = h.shape[0]
    low = [[None] * size for _ in range(size)]
    inv_diag = []
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(size):
            s = h[j, j] if diag is None else diag[j]
            for k in range(j):
                s = s - low[j][k] * low[j][k]
            d = np.sqrt(s)
            low[j][j] = d
            inv_diag.append(1.0 / d)
            for i in range(j + 1, size):
                s = h[i, j]
                for k in range(j):
                    s = s - low[i][k] * low[j][k]
                low[i][j] = s * inv_diag[j]
    return low, inv_diag


def cholesky_solve(h: np.ndarray, b: np.ndarray, diag: np.ndarray | None = None) -> np.ndarray:
    """Solution ``x (P, n)`` of ``h x = b`` for a stack ``h (P, P, n)`` of symmetric positive
    definite matrices (lower triangle read; the diagonal from ``diag (P, n)`` when given) and
    ``b (P, n)``; a new array."""
    size, n = b.shape
    low, inv_diag = _cholesky(h, diag)
    z = []
    for i in range(size):  # L z = b
        s = b[i]
        for k in range(i):
            s = s - low[i][k] * z[k]
        z.append(s * inv_diag[i])
    x = np.empty((size, n))
    for i in reversed(range(size)):  # Lᵀ x = z
        s = z[i]
        for k in range(i + 1, size):
            s = s - low[k][i] * x[k]
        np.multiply(s, inv_diag[i], out=x[i])
    return x


def spd_inverse(h: np.ndarray) -> np.ndarray:
    """Inverses ``(n, P, P)`` of the information matrices ``JᵀJ`` ``h (P, P, n)`` (lower triangle
    read, as :func:`gram` makes them); NaN where (near-)singular: where the determinant of the
    correlation matrix, ``det / ∏ diagonal``, is at most 1e-12."""
    size, _, n = h.shape
    if not _unrolled(size, n):
        h = _symmetric_stack(h)  # (n, P, P)
        out = np.full_like(h, np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            ok = np.linalg.det(h) / np.prod(h.reshape(n, -1)[:, :: size + 1], axis=1) > 1e-12
        if ok.any():
            out[ok] = np.linalg.inv(h[ok])
        return out
    diag = h.reshape(size * size, n)[:: size + 1]
    out = np.empty((n, size, size))
    low, inv_diag = _cholesky(h)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.prod(np.square([low[j][j] for j in range(size)]) / diag, axis=0)
    ok = ratio > 1e-12  # NaN (not positive definite) is not ok either
    m = [[None] * size for _ in range(size)]  # m = L⁻¹ (lower triangular); h⁻¹ = mᵀ m
    with np.errstate(invalid="ignore", over="ignore"):  # not positive definite: NaN, set below
        for i in range(size):
            m[i][i] = inv_diag[i]
            for j in range(i):
                s = low[i][j] * m[j][j]
                for k in range(j + 1, i):
                    s = s + low[i][k] * m[k][j]
                m[i][j] = -s * inv_diag[i]
    for i in range(size):
        for j in range(i + 1):
            s = m[i][i] * m[i][j]
            for k in range(i + 1, size):
                s = s + m[k][i] * m[k][j]
            out[:, i, j] = s
            if j != i:
                out[:, j, i] = s
    out[~ok] = np.nan
    return out
