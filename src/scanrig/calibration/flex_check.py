"""Does a board calibrated as flat look bent? A one-step estimate of its flex from the rigid solution.

For a planar target without ``flex = true``, the two flex terms of
:func:`scanrig.targets.target.flex_shape` are appended to the solved parameters at zero and one
Gauss–Newton step is taken from the rigid solution: with ``A = JᵀJ`` of the augmented weighted
Jacobian (prior rows included, with no flex columns) and the solution's gradient, zero for every
solved parameter, ``J_fᵀ r`` for the flex terms,

    c = -(A⁻¹)_ff J_fᵀ r,    Σ_c = σ² (A⁻¹)_ff

(``f`` the flex terms, ``σ`` the solution's residual scale). The bundle adjustment is nearly linear
in ``c`` for bends of millimetres, so this is the flex the full solve with ``flex = true`` would
find, to first order, at the cost of one sparse factorisation. A term beyond
:data:`FLEX_WARN_SIGMAS` of its σ gives a warning: the cross-validation flags a 1 mm bend of a
0.5 m board in only ~4 of 5 sessions of 16-30 shots, this test in all of them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse

from scanrig.calibration.bundle import BundleResult, Problem, State
from scanrig.calibration.lm import normal_equations, solve_spd
from scanrig.targets import Target

#: A flex term beyond this many σ of zero is warned about: under the flat-board model each
#: exceeds it with probability 6e-7.
FLEX_WARN_SIGMAS = 5.0


def flex_step(result: BundleResult, target: Target) -> tuple[np.ndarray, np.ndarray] | None:
    """The flex a flat-board solution leaves in its residuals (see the module docstring).

    Parameters
    ----------
    result : BundleResult
        A solution with a rigid planar ``target``.
    target : Target

    Returns
    -------
    flex_m, flex_std_m : ndarray of shape (2,)
        ``(c_x, c_y)`` and their σ, metres; None when the augmented normal matrix is singular.
    """
    obs = result.obs.subset(result.inliers)
    p_target, _ = target.lookup(obs.point_id)
    n = result.layout.size
    layout = dataclasses.replace(result.layout, flex=slice(n, n + 2), size=n + 2)
    template = State(result.state.cameras, result.state.world_from_target, np.zeros(2))
    r, J = Problem(obs, p_target, layout, template, np.sqrt(obs.weight),
                   flex_dir=target.flex_directions(obs.point_id))(np.append(result.x, [0.0, 0.0]), True)
    prior_rows = result.jacobian[J.shape[0]:]
    J = scipy.sparse.vstack([J, scipy.sparse.hstack([prior_rows, scipy.sparse.csr_matrix((prior_rows.shape[0], 2))])])
    A, _ = normal_equations(J, np.zeros(J.shape[0]))
    scale = np.sqrt(np.maximum(A.diagonal(), 1e-300))
    A_scaled = A.multiply(1.0 / scale[:, None]).multiply(1.0 / scale[None, :]).tocsc()
    unit = np.zeros((n + 2, 2))
    unit[n:, :] = np.eye(2)
    try:
        inv_ff = (solve_spd(A_scaled, unit)[n:] / scale[n:, None]) / scale[None, n:]
    except RuntimeError:
        return None
    gradient_f = J[:len(r)][:, n:].T @ r
    return -inv_ff @ gradient_f, result.sigma_px * np.sqrt(np.maximum(np.diag(inv_ff), 0.0))


def flex_warning(result: BundleResult, target: Target) -> list[str]:
    """One line (as a list of 0 or 1) when a rigid planar target looks bent beyond
    :data:`FLEX_WARN_SIGMAS`; nothing for a cube or a target with ``flex = true``."""
    if target.flex or not target.is_planar:
        return []
    step = flex_step(result, target)
    if step is None or not np.any(np.abs(step[0]) > FLEX_WARN_SIGMAS * step[1]):
        return []
    (cx, cy), (sx, sy) = step[0] * 1000.0, step[1] * 1000.0
    return [f"target: the board looks bent (sag at the centre along x {cx:.3f} ± {sx:.3f} mm, along y "
            f"{cy:.3f} ± {sy:.3f} mm, estimated from the flat-board solution): set flex = true in target.toml "
            "to estimate the bend, or use a flatter board"]
