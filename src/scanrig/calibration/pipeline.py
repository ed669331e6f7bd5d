"""Calibration from detections: initialise, bundle-adjust, judge (:func:`calibrate`).

Also the target's detection in a session's images (:func:`detect_session`), the calibration's
samples and the pose of a target in one image. A session folder's whole calibration, with its
known intrinsics and its outputs, is :mod:`scanrig.calibration.session_calibration`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanrig.calibration.bundle import BundleResult, bundle_adjust
from scanrig.calibration.camera_agreement import CameraAgreement, agreement_warnings, camera_agreement
from scanrig.calibration.cross_validation import (SPLITS, CrossValidation, combine_splits, compare_halves,
                                                  cross_validation_warnings, split_halves)
from scanrig.calibration.flex_check import flex_warning
from scanrig.calibration.init import MIN_POINTS_PER_PLANE, Initialisation, initialise
from scanrig.calibration.intrinsics_prior import (prior_pull_warning, solve_constraints, undetermined_intrinsics,
                                                  with_known_intrinsics)
from scanrig.calibration.observations import Observations
from scanrig.calibration.summary import dropped_view_warnings
from scanrig.calibration.uncertainty import Uncertainty, covariance, parameter_covariance, projection_uncertainty
from scanrig.errors import FileFormatError, InputError
from scanrig.geometry.rig import Rig
from scanrig.geometry.uncertainty import MAD_TO_SIGMA
from scanrig.targets import Target

#: Camera models a calibration may fit.
CALIBRATION_MODELS = ("opencv4", "opencv5", "opencv8")
#: Fewest views of one board (planes) per camera: two homographies fix fx, fy, cx, cy (zero skew).
MIN_PLANES_PER_CAMERA = 2
#: Fewest shots in each half of a cross-validation split.
MIN_SHOTS_PER_HALF = 3
REPORT_DIR = "calibration_report"
#: :func:`locate_target`: corners beyond this many robust sigmas of reprojection error (and
#: beyond LOCATE_MIN_GATE_PX) are left out of the pose, in at most LOCATE_ROUNDS solves.
LOCATE_OUTLIER_SIGMAS = 5.0
LOCATE_MIN_GATE_PX = 0.05
LOCATE_ROUNDS = 4


@dataclass
class CalibrationResult:
    """Everything a calibration produced."""

    rig: Rig
    bundle: BundleResult
    uncertainty: Uncertainty
    init: Initialisation
    target: Target
    working_distance_m: dict
    projection_sigma_px: dict
    cross_validation: CrossValidation | None = None
    camera_agreement: dict[str, CameraAgreement | None] | None = None
    warnings: list = field(default_factory=list)
    not_found: list = field(default_factory=list)
    known_intrinsics: dict = field(default_factory=dict)

    def camera_info(self) -> dict:
        """Per-camera quality fields for ``rig.toml``."""
        counts = np.bincount(self.bundle.obs.camera[self.bundle.inliers], minlength=len(self.rig))
        return {name: {"rms_px": round(self.bundle.rms_px(c), 6),
                       "params_std": [float(v) for v in self.uncertainty.params_std[name]],
                       "n_observations": int(counts[c])}
                for c, name in enumerate(self.rig.names)}


def check_observations(obs: Observations, target: Target, known_intrinsics: tuple[str, ...] = ()) -> None:
    """Bad-input checks before any solve: every camera sees the target in enough views (one is
    enough for a camera in ``known_intrinsics``: only its pose is left to find)."""
    board_idx = target.board_of(obs.point_id)
    unknown = board_idx < 0
    if np.any(unknown):
        raise InputError(f"detections name point ids the target does not have, e.g. "
                         f"{sorted(set(obs.point_id[unknown].tolist()))[:5]}; check target.toml")
    key = (obs.camera * len(obs.shot_names) + obs.shot) * len(target.boards) + board_idx
    ukey, n = np.unique(key, return_counts=True)
    planes_cam = ukey[n >= MIN_POINTS_PER_PLANE] // (len(obs.shot_names) * len(target.boards))
    per_camera = np.bincount(planes_cam, minlength=len(obs.camera_names))
    for c, name in enumerate(obs.camera_names):
        if not np.any(obs.camera == c):
            raise InputError(f"camera {name!r}: the target was never found in its calibration images")
        if name in known_intrinsics and per_camera[c] == 0:
            raise InputError(f"camera {name!r}: no view shows {MIN_POINTS_PER_PLANE} or more points of one board; "
                             "at least one is needed for its pose")
        if name not in known_intrinsics and per_camera[c] < MIN_PLANES_PER_CAMERA:
            raise InputError(f"camera {name!r}: the target was found in {per_camera[c]} usable view(s); "
                             f"at least {MIN_PLANES_PER_CAMERA} are needed (views of a board at different tilts)")


def calibrate(obs: Observations, target: Target, model: str | dict = "opencv5",
              fixed_params: dict | None = None, cross_validate: bool = True,
              known_intrinsics: dict | None = None, refine_intrinsics: bool = False) -> CalibrationResult:
    """Calibrate every camera jointly from observations.

    Parameters
    ----------
    obs : Observations
    target : Target
    model : str or dict
        One of :data:`CALIBRATION_MODELS` for all cameras, or ``camera -> model``.
    fixed_params : dict, optional
        ``camera -> parameter names held at their initial value``.
    cross_validate : bool
        Also cross-validate: calibrate the halves of each split of the shots
        (:data:`~scanrig.calibration.cross_validation.SPLITS`) apart and compare them (the splits
        whose halves have :data:`MIN_SHOTS_PER_HALF` shots and can be solved), and solve each
        camera's corners alone against the rig (:mod:`scanrig.calibration.camera_agreement`).
    known_intrinsics : dict, optional
        ``camera -> KnownIntrinsics`` (:mod:`scanrig.calibration.intrinsics_prior`): these
        cameras keep their model and intrinsics, held fixed or, with ``refine_intrinsics``,
        refined under priors with their standard deviations.
    refine_intrinsics : bool

    Raises
    ------
    InputError
        Too few views, a camera that never sees the target, a disconnected camera graph,
        ``refine_intrinsics`` for known intrinsics without standard deviations.
    """
    known = known_intrinsics or {}
    models = dict(model) if isinstance(model, dict) else {name: model for name in obs.camera_names}
    models.update({name: k.camera.model for name, k in known.items()})
    fixed, priors = solve_constraints(known, refine_intrinsics)
    fixed = {name: tuple((fixed_params or {}).get(name, ())) + fixed.get(name, ())
             for name in obs.camera_names}
    for name in obs.camera_names:
        if name not in known and models.get(name) not in CALIBRATION_MODELS:
            raise InputError(f"camera {name!r}: model must be one of {list(CALIBRATION_MODELS)}, "
                             f"got {models.get(name)!r}")
    check_observations(obs, target, tuple(known))
    init, bundle = _solve(obs, target, models, fixed, priors, known)
    unc = covariance(bundle)
    rig = Rig(bundle.state.cameras)
    distance = _working_distances(bundle, target)
    sigma_map = {name: projection_uncertainty(bundle, unc, c, distance[name])[1]
                 for c, name in enumerate(rig.names)}
    warnings = list(unc.warnings)
    warnings += [line for cam in rig.cameras if cam.name not in known
                 if (line := undetermined_intrinsics(cam.name, unc.poorly_determined[cam.name]))]
    warnings += [w for k in known.values() for w in k.warnings]
    if refine_intrinsics:
        warnings += [line for cam in rig.cameras if cam.name in known
                     if (line := prior_pull_warning(cam, known[cam.name]))]
    warnings += dropped_view_warnings(init.dropped_views)
    warnings += flex_warning(bundle, target)
    n_out = len(bundle.outliers)
    if n_out > 0.05 * len(obs):
        warnings.append(f"{n_out} of {len(obs)} detections rejected as outliers (> 5 %): check the detections")
    result = CalibrationResult(rig, bundle, unc, init, target, distance, sigma_map, warnings=warnings,
                               known_intrinsics=known)
    if cross_validate:
        result.cross_validation = _cross_validate(result, fixed, priors)
        result.warnings += cross_validation_warnings(result.cross_validation)
        result.camera_agreement = camera_agreement(bundle, unc.covariance, target, fixed, priors)
        result.warnings += agreement_warnings(result.camera_agreement)
    return result


def _solve(obs, target, models, fixed_params, priors, known) -> tuple[Initialisation, BundleResult]:
    """Initialise and bundle-adjust; the intrinsics of ``known`` replace the initial ones."""
    init = initialise(obs, target, models)
    init.cameras = with_known_intrinsics(init.cameras, known)
    return init, bundle_adjust(obs, target, init.cameras, init.world_from_target, init.reference_shot,
                               fixed_params, priors=priors)


def _working_distances(bundle: BundleResult, target: Target) -> dict:
    """Median distance (m) from each camera to the target points it observed."""
    p_target, _ = target.lookup(bundle.obs.point_id)
    out = {}
    for c, cam in enumerate(bundle.state.cameras):
        rows = np.flatnonzero((bundle.obs.camera == c) & bundle.inliers)
        dist = []
        for s in np.unique(bundle.obs.shot[rows]):
            sel = rows[bundle.obs.shot[rows] == s]
            p_world = bundle.state.world_from_target[s].apply(p_target[sel])
            dist.append(np.linalg.norm(p_world - cam.center_world, axis=1))
        out[cam.name] = float(np.median(np.concatenate(dist)))
    return out


def _cross_validate(full: CalibrationResult, fixed_params, priors=None) -> CrossValidation | None:
    """Calibrate the two halves of each split of the shots apart and compare them, pooled over the
    splits (None when no split's halves can be solved).

    The splits divide the shots the full solution solved, in the session's order (a shot without
    a pose would leave its half short, most of all in the first/second halves split when the
    target left the view for the end of the session).
    """
    solved = np.array([s for s, pose in enumerate(full.bundle.state.world_from_target) if pose is not None])
    per_split = {}
    for name, split in SPLITS.items():
        halves = [_solve_half(full, solved[shots], fixed_params, priors)
                  for shots in split_halves(len(solved), split)]
        if all(h is not None for h in halves):
            per_split[name] = compare_halves(full.bundle, halves, [parameter_covariance(h)[0] for h in halves],
                                             full.working_distance_m)
    return combine_splits(per_split) if per_split else None


def _solve_half(full: CalibrationResult, shots: np.ndarray, fixed_params, priors=None) -> BundleResult | None:
    """Bundle adjustment of some shots alone, or None when fewer than :data:`MIN_SHOTS_PER_HALF`
    of them were solved in the full calibration or they cannot be solved alone.

    The half keeps the corners the full solution kept (its outlier rejection, from all views, is
    better informed than one from half of them) and solves plain least squares on them, which is
    what the robust solve ends with too. It starts from the full solution (its cameras and these
    shots' poses), about one σ from the half's own minimum, so it converges in a few iterations
    without an initialisation; the world frame is the full solution's, held by the half's shot
    with the most corners.
    """
    obs, world_from_target = full.bundle.obs, full.bundle.state.world_from_target
    shots = np.array([s for s in shots if world_from_target[s] is not None], dtype=int)
    if len(shots) < MIN_SHOTS_PER_HALF:
        return None
    sub = obs.subset(np.isin(obs.shot, shots) & full.bundle.inliers)
    start = [pose if s in shots else None for s, pose in enumerate(world_from_target)]
    reference = int(np.argmax(np.bincount(sub.shot, minlength=len(obs.shot_names))))
    try:
        check_observations(sub, full.target, tuple(full.known_intrinsics))
        return bundle_adjust(sub, full.target, full.bundle.state.cameras, start, reference, fixed_params,
                             robust=False, priors=priors)
    except InputError:
        return None


def detect_session(session, target: Target, cameras: list[str] | None = None, progress=None,
                   stage: str = "calibration"):
    """Detect the target in every calibration image of a session (of ``stage``: ``calibration``
    or ``calibration_intrinsic``).

    Returns
    -------
    obs : Observations
    not_found : list of (camera, shot)
        Images in which the target was not found.

    Raises
    ------
    FileFormatError
        An image whose size differs from the camera's other images, an unreadable image, or one
        showing a ChArUco board of the other layout than declared (legacy or current).
    """
    from scanrig.calibration.detect import BoardLayoutError, detect_target
    from scanrig.io.session import read_image

    cameras = cameras or session.camera_names(stage)
    frames = session.frames(stage, cameras)
    sizes: dict[str, tuple[int, int]] = {}
    first: dict[str, Path] = {}
    parts, not_found = [], []
    jobs = [(stem, cam, path) for stem, by_cam in frames.items() for cam, path in by_cam.items()]
    for stem, cam, path in jobs:
        img = read_image(path)
        size = (img.shape[1], img.shape[0])
        if cam not in sizes:
            sizes[cam], first[cam] = size, path
        elif size != sizes[cam]:
            raise FileFormatError(path, f"image is {size[0]}x{size[1]} but {first[cam].name} of camera "
                                        f"{cam!r} is {sizes[cam][0]}x{sizes[cam][1]}; one camera, one image size")
        try:
            det = detect_target(img, target)
        except BoardLayoutError as exc:
            raise FileFormatError(path, str(exc)) from None
        if len(det.point_ids):
            parts.append((cam, stem, det.point_ids, det.uv, det.weight))
        else:
            not_found.append((cam, stem))
        if progress is not None:
            progress()
    missing = [c for c in cameras if c not in sizes]
    if missing:
        raise FileFormatError(session.root / stage, f"cameras {missing} have no calibration images")
    return Observations.concatenate(parts, cameras, list(frames), sizes), not_found


def sample_states(result: CalibrationResult, n_samples: int, rng: np.random.Generator) -> list:
    """Calibrations drawn from the solution's covariance (intrinsics, camera and target poses).

    Returns
    -------
    list of State
        ``n_samples`` states (cameras and ``world_from_target`` of every shot, as
        ``result.bundle.state``), each from ``x + L z`` with ``L Lᵀ`` the parameter covariance
        and ``z`` standard normal.
    """
    from scanrig.calibration.bundle import unpack

    eigval, eigvec = np.linalg.eigh(result.uncertainty.covariance)
    root = eigvec * np.sqrt(np.maximum(eigval, 0.0))
    draws = result.bundle.x + rng.standard_normal((n_samples, len(eigval))) @ root.T
    return [unpack(x, result.bundle.layout, result.bundle.state) for x in draws]


def shot_index(result: CalibrationResult, shot: str) -> int | None:
    """Index of a calibration shot in the bundle's state, or None when it was not solved."""
    names = result.bundle.obs.shot_names
    if shot not in names or result.bundle.state.world_from_target[names.index(shot)] is None:
        return None
    return names.index(shot)


def locate_target(image, target: Target, camera):
    """``world_from_target`` of the target in one image of a calibrated camera, or None when the
    target is not found there.

    Detection and PnP with the camera's intrinsics, then PnP again without the corners whose
    reprojection error exceeds :data:`LOCATE_OUTLIER_SIGMAS` robust sigmas (at least
    :data:`LOCATE_MIN_GATE_PX`): a laser stripe across a corner pulls it by up to pixels, and a
    few such corners move the pose by a millimetre.
    """
    from scanrig.calibration.detect import detect_target
    from scanrig.calibration.init import view_pose

    det = detect_target(image, target)
    ids, uv = det.point_ids, det.uv
    cam_from_target = None
    for _ in range(LOCATE_ROUNDS):
        if len(ids) == 0:
            return None
        cam_from_target, _ = view_pose(camera, target, ids, uv)
        if cam_from_target is None:
            return None
        p_target, _ = target.lookup(ids)
        error_px = np.linalg.norm(camera.with_pose(cam_from_target).project(p_target) - uv, axis=1)
        gate = max(LOCATE_OUTLIER_SIGMAS * MAD_TO_SIGMA * float(np.median(error_px)), LOCATE_MIN_GATE_PX)
        keep = error_px <= gate
        if keep.all():
            break
        ids, uv = ids[keep], uv[keep]
    return camera.cam_from_world.inverse() @ cam_from_target
