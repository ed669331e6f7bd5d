"""Do the cameras agree about where the target was? Each camera's corners alone against the rig.

A joint calibration gives every shot one target pose, shared by all cameras. That holds when the
cameras' frames are simultaneous and nothing moved between them; when the frames are not
simultaneous (webcams on their own clocks, a board moved by hand) every camera sees the board
somewhere else, and the joint solve absorbs the disagreement into the cameras' intrinsics and
poses. Errors shared by all corners of one view (motion blur, a rolling shutter) do the same on
a smaller scale. The halves of the shots (:mod:`scanrig.calibration.cross_validation`) cannot see
that, since every view has it; the cameras apart can.

For each camera its inlier corners are solved again alone, with a target pose of its own per shot
(its intrinsics and the same held and prior terms as in the rig), starting from the rig's
solution. The rig is the special case of that model in which the poses are the shared ones, so
the camera's weighted residual sum can only fall; if the shared poses are right it falls by
chi-square over the difference in degrees of freedom. The camera's degrees of freedom in a solve
are its residuals less the leverages of its rows there, ``2 n - <(JᵀJ)⁻¹, J_cᵀ J_c>`` (alone and
without priors ``2 n - p``, ``p`` its own unknowns), so

``F = ((SSR_rig - SSR_alone) / Δdof) / (SSR_alone / dof_alone)``

follows Fisher's F(Δdof, dof_alone), and ``ratio = sqrt(F)`` is the rig's extra misfit per
constraint in units of the camera's own noise: 1 when the cameras agree. On the 240 clean
simulated 3-camera sessions of ``benchmarks/bench_cross_validation.py`` (10-80 shots) the ratios
were 0.78-1.29, the smallest probability 0.0026; on the real 4-webcam ChArUco rig of ``tests/data/caliscope-4cam-charuco``
1.4-6.9, probabilities 1e-10 to 1e-290; on the real stereo pairs of
``tests/data/opencv-stereo-9x6`` and ``mrpt-stereo-9x6`` 2.6-3.2 (0.01-0.02 px of extra RMS).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import f as fisher_f

from scanrig.calibration.bundle import BundleResult, bundle_adjust
from scanrig.calibration.observations import Observations
from scanrig.calibration.uncertainty import parameter_covariance
from scanrig.errors import InputError

#: What a user can do when the cameras disagree (summary.txt lists these under the warning).
CAUSES = (
    "frames not taken at the same instant while the target moved (webcams on their own clocks, a board "
    "moved by hand): hold the target still for each shot, or synchronise the cameras",
    "a camera that moved or refocused during the session: fix it, and calibrate again",
    "errors shared by the corners of one view (motion blur, a rolling shutter, uneven light, a steep view "
    "angle): the sigmas assume independent corners, so read them as lower bounds, or take sharper views",
    "intrinsics the rig views cannot fix (one distance, the target small in the image): calibrate them "
    "first (calibration_intrinsic/<camera>/ images, or --intrinsics FILE)",
)
#: A camera is warned about when the chance of its ratio or a larger one, with the cameras in
#: agreement, is below this: about one false alarm in a million cameras.
P_WARN = 1e-6


@dataclass(frozen=True)
class CameraAgreement:
    """One camera's corners alone against the rig.

    Attributes
    ----------
    rms_alone_px, rms_rig_px : float
        RMS reprojection error of the camera's inlier corners (``sqrt(mean |e|²)``, as
        :meth:`~scanrig.calibration.bundle.BundleResult.rms_px`), solved alone and in the rig.
    ratio : float
        ``sqrt(F)``: the rig's extra misfit per constraint in units of the camera's own noise.
    dof : float
        The constraints the shared poses add (``Δdof``, from the leverages: not an integer).
    p_value : float
        Chance of this ratio or a larger one when the cameras agree.
    """

    rms_alone_px: float
    rms_rig_px: float
    ratio: float
    dof: float
    p_value: float


def camera_agreement(bundle: BundleResult, covariance: np.ndarray, target, fixed_params: dict,
                     priors: dict | None = None) -> dict[str, CameraAgreement | None]:
    """Each camera's corners solved alone against the rig (module docstring).

    Parameters
    ----------
    bundle : BundleResult
        The rig's solution.
    covariance : ndarray of shape (n_params, n_params)
        Its parameter covariance ``σ² (JᵀJ)⁻¹`` (:class:`~scanrig.calibration.uncertainty.Uncertainty`).
    target : Target
    fixed_params, priors : dict
        As given to the rig's :func:`~scanrig.calibration.bundle.bundle_adjust`.

    Returns
    -------
    dict
        ``camera -> CameraAgreement``, or None for a camera that shares no shot with another camera
        (nothing to disagree about), or whose views cannot be solved alone.
    """
    obs = bundle.obs
    inliers = np.flatnonzero(bundle.inliers)
    rig_leverage = _leverage_sums(bundle.jacobian, covariance / bundle.sigma_px ** 2,
                                  np.repeat(obs.camera[inliers], 2), len(obs.camera_names))
    out = {}
    for c, name in enumerate(obs.camera_names):
        rows = inliers[obs.camera[inliers] == c]
        alone = _solve_alone(bundle, c, rows, target, fixed_params, priors)
        if alone is None or alone.sigma_px == 0.0:
            out[name] = None
            continue
        alone_leverage = _leverage_sums(alone.jacobian, parameter_covariance(alone)[0] / alone.sigma_px ** 2,
                                        np.zeros(2 * len(rows), dtype=np.int64), 1)[0]
        dof_alone = 2 * len(rows) - alone_leverage
        d_dof = alone_leverage - rig_leverage[c]
        if d_dof < 1.0 or dof_alone < 1.0:
            out[name] = None
            continue
        w = obs.weight[rows, None]
        ssr_rig = float(np.sum(w * bundle.residuals_px[rows] ** 2))
        ssr_alone = float(np.sum(w * alone.residuals_px ** 2))
        f = max(ssr_rig - ssr_alone, 0.0) / d_dof / (ssr_alone / dof_alone)
        out[name] = CameraAgreement(alone.rms_px(), bundle.rms_px(c), float(np.sqrt(f)), float(d_dof),
                                    float(fisher_f.sf(f, d_dof, dof_alone)))
    return out


def _leverage_sums(jacobian, inverse_normal: np.ndarray, group_of_row: np.ndarray, n_groups: int) -> np.ndarray:
    """Per group of residual rows, the sum of their leverages in a solve, ``<(JᵀJ)⁻¹, J_gᵀ J_g>``.

    Parameters
    ----------
    jacobian : scipy.sparse matrix of shape (R, P)
        The solve's weighted Jacobian: the observation rows first (two per inlier corner), then
        any prior rows (no group: they count in ``JᵀJ`` only).
    inverse_normal : ndarray of shape (P, P)
        ``(JᵀJ)⁻¹``, the pseudo-inverse where the data leave directions open.
    group_of_row : ndarray of shape (R_obs,), int
        The group of each observation row.
    n_groups : int

    Returns
    -------
    ndarray of shape (n_groups,)
        Without priors and at full rank, a group's leverages sum to the parameters it alone
        determines; over all rows, to ``P``.
    """
    J = jacobian.tocsr()[:len(group_of_row)]
    return np.array([float((J_g.T @ J_g).multiply(inverse_normal).sum())
                     for J_g in (J[group_of_row == g] for g in range(n_groups))])


def _solve_alone(bundle: BundleResult, camera: int, rows: np.ndarray, target, fixed_params: dict,
                 priors: dict | None) -> BundleResult | None:
    """Plain least squares of one camera's corners ``rows`` with a target pose per shot, from the
    rig's solution; None when it shares no shot with another camera or cannot be solved alone."""
    obs = bundle.obs
    shots = np.unique(obs.shot[rows])
    others = np.unique(obs.shot[bundle.inliers & (obs.camera != camera)])
    if not np.isin(shots, others).any():
        return None
    name = obs.camera_names[camera]
    sub = Observations(np.zeros(len(rows), dtype=np.int64), obs.shot[rows], obs.point_id[rows], obs.uv[rows],
                       obs.weight[rows], (name,), obs.shot_names, {name: obs.image_sizes[name]})
    start = [pose if s in shots else None for s, pose in enumerate(bundle.state.world_from_target)]
    reference = int(np.argmax(np.bincount(sub.shot, minlength=len(obs.shot_names))))
    keep = {name: fixed_params.get(name, ())} if fixed_params else None
    prior = {name: priors[name]} if priors and name in priors else None
    try:
        return bundle_adjust(sub, target, [bundle.state.cameras[camera]], start, reference, keep,
                             robust=False, priors=prior)
    except InputError:
        return None


def agreement_warnings(agreement: dict | None) -> list[str]:
    """One line per camera whose corners fit far better alone than in the rig (``p_value`` below
    :data:`P_WARN`)."""
    if not agreement:
        return []
    return [f"{name}: its corners fit {a.rms_alone_px:.2f} px alone but {a.rms_rig_px:.2f} px in the rig "
            f"({a.ratio:.1f} x its own noise over {a.dof:.0f} constraints, chance {a.p_value:.1g}): the cameras "
            "disagree about where the target was, and the rig's sigmas are too small (what to do: "
            "calibration_report/summary.txt)"
            for name, a in agreement.items() if a is not None and a.p_value < P_WARN]
