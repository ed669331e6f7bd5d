"""A small Levenberg–Marquardt solver over a sparse Jacobian, for calibration-sized problems.

Written here rather than calling ``scipy.optimize.least_squares`` because (see
``reference/dependencies.md`` §6) its sparse path takes inexact lsmr steps that crawl on badly
scaled calibration problems. Here every step solves the damped normal equations exactly with a
sparse LU factorisation (SuperLU): ``JᵀJ`` of a calibration is block-sparse (target poses only
couple to cameras), and SuperLU stays fast on a loaded machine where multithreaded dense BLAS
calls on small matrices can be slowed a hundredfold by thread contention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

#: Stop when one step lowers the cost by less than this fraction (1e-10 of the cost moves the
#: parameters by at most ~1e-3 sigma for the problem sizes here: far below the reported uncertainty).
COST_RTOL = 1e-10
#: Stop when the scaled step is below this fraction of the scaled parameter vector.
STEP_RTOL = 1e-12


@dataclass
class LMResult:
    """Outcome of :func:`levenberg_marquardt`."""

    x: np.ndarray
    cost: float
    iterations: int
    converged: bool


def levenberg_marquardt(fun, x0: np.ndarray, max_iterations: int = 100, cost_rtol: float = COST_RTOL) -> LMResult:
    """Minimise ``|r(x)|²``.

    Parameters
    ----------
    fun : callable
        ``fun(x, jacobian: bool)`` returns ``r`` of shape (m,), and, when ``jacobian`` is true,
        also ``J`` of shape (m, n) (scipy.sparse or dense). Non-finite residuals, or a
        ``ValueError`` raised for ``x`` outside the model's domain, make a step fail.
    x0 : ndarray of shape (n,)
    max_iterations : int
    cost_rtol : float
        Stop when a step lowers the cost by less than this fraction.

    Returns
    -------
    LMResult
    """
    x = np.asarray(x0, dtype=np.float64).copy()
    r, J = fun(x, True)
    cost = float(r @ r)
    lam = 1e-4
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):
        A, g = normal_equations(J, r)
        # Marquardt's scaling: damp each parameter relative to its own curvature.
        diag = A.diagonal()
        d = np.maximum(diag, 1e-12 * max(diag.max(), 1e-300))
        improved = False
        while lam < 1e16:
            try:
                step = -solve_spd(A + scipy.sparse.diags(lam * d), g)
            except RuntimeError:
                lam *= 10.0
                continue
            x_new = x + step
            try:
                r_new = fun(x_new, False)
                cost_new = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else np.inf
            except ValueError:  # the step left the model's domain (e.g. a negative focal length)
                cost_new = np.inf
            if cost_new < cost:
                improved = True
                break
            lam *= 10.0
        if not improved:
            converged = True  # no direction lowers the cost: a minimum to machine precision
            break
        small_step = np.sqrt(np.sum(step ** 2 * d)) <= STEP_RTOL * (np.sqrt(np.sum(x ** 2 * d)) + STEP_RTOL)
        small_gain = cost - cost_new <= cost_rtol * cost
        x, cost = x_new, cost_new
        r, J = fun(x, True)
        lam = max(lam / 10.0, 1e-12)
        if small_step or small_gain:
            converged = True
            break
    return LMResult(x, cost, it, converged)


def normal_equations(J, r: np.ndarray):
    """Sparse ``JᵀJ`` (n, n, CSC) and ``Jᵀr`` (n,) from a sparse or dense Jacobian."""
    J = scipy.sparse.csr_matrix(J)
    return (J.T @ J).tocsc(), J.T @ r


def solve_spd(A, b: np.ndarray) -> np.ndarray:
    """Solve ``A x = b`` for a sparse symmetric positive-definite ``A`` (RuntimeError if singular).

    ``b`` may be (n,) or (n, k).
    """
    x = scipy.sparse.linalg.splu(scipy.sparse.csc_matrix(A)).solve(np.asarray(b, dtype=np.float64))
    if not np.all(np.isfinite(x)):
        raise RuntimeError("singular matrix")
    return x
