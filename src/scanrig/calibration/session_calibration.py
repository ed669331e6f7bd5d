"""Calibration of a session folder: its images, its known intrinsics, its outputs.

:func:`calibrate_session` checks every input before computing anything and writes nothing until
the solve has succeeded: ``rig.toml`` (atomically, last) and the report folder
``calibration_report/`` (summary, detections, outliers, residual and uncertainty plots). Cameras
with ``calibration_intrinsic/<camera>/`` images are first calibrated alone from them
(:mod:`scanrig.calibration.intrinsics_prior` says how known intrinsics enter the joint solve).
The solve itself is :func:`scanrig.calibration.pipeline.calibrate`.
"""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np

from scanrig.calibration.corners_csv import read_corners_csv, write_corners_csv
from scanrig.calibration.intrinsics_prior import (INTRINSIC_STAGE, INTRINSIC_TARGET, KnownIntrinsics, check_size,
                                                  read_intrinsics_file, undetermined_intrinsics)
from scanrig.calibration.observations import Observations
from scanrig.calibration.pipeline import REPORT_DIR, CalibrationResult, calibrate, detect_session
from scanrig.calibration.summary import format_summary, write_outliers_csv, write_summary_json
from scanrig.errors import FileFormatError, InputError
from scanrig.io.atomic import write_text_atomic
from scanrig.io.rig_file import save_rig
from scanrig.io.session import Session, natural_key, read_image
from scanrig.targets import load_target

#: A camera calibrated alone from its ``calibration_intrinsic/`` views is refused when its focal
#: length is known only to this fraction of itself (1 sigma): a 5 % focal error scales every
#: distance the rig measures by about as much. Four chessboard views of a real webcam gave
#: fx 212 ± 120 px (the lens's is about 904); three good Ciclop views give 1430 ± 1.6 px.
MAX_FOCAL_SIGMA_FRACTION = 0.05


def calibrate_session(root: str | Path, model: str = "opencv5", corners_csv: str | Path | None = None,
                      cross_validate: bool = True, plots: bool = True, command_line: str = "",
                      progress_factory=None, intrinsics: str | Path | None = None,
                      refine_intrinsics: bool = False) -> CalibrationResult:
    """Calibrate a session folder and write ``rig.toml`` and ``calibration_report/``.

    Parameters
    ----------
    root : str or Path
        Session folder (DESIGN.md §4).
    model : str
        Camera model for every camera (:data:`~scanrig.calibration.pipeline.CALIBRATION_MODELS`).
    corners_csv : path, optional
        Use these detections (:mod:`scanrig.calibration.corners_csv`) instead of detecting;
        image sizes are then read from the first calibration image of each camera.
    cross_validate, plots : bool
    command_line : str
        Recorded in ``rig.toml``.
    progress_factory : callable, optional
        ``progress_factory(total) -> advance()`` for a progress display during detection.
    intrinsics : path, optional
        A ``rig.toml`` or OpenCV YAML whose cameras' intrinsics are held fixed (or, with
        ``refine_intrinsics``, refined under priors with their ``params_std``); cameras with
        ``calibration_intrinsic/<camera>/`` images are first calibrated alone from them
        (:mod:`scanrig.calibration.intrinsics_prior`).
    refine_intrinsics : bool
    """
    result, obs = solve_session(root, model, corners_csv, cross_validate, progress_factory, intrinsics,
                                refine_intrinsics)
    write_session_outputs(root, result, obs, plots, command_line)
    return result


def solve_session(root: str | Path, model: str = "opencv5", corners_csv: str | Path | None = None,
                  cross_validate: bool = True, progress_factory=None, intrinsics: str | Path | None = None,
                  refine_intrinsics: bool = False) -> tuple[CalibrationResult, Observations]:
    """Detect and calibrate a session folder without writing anything.

    Parameters are those of :func:`calibrate_session`. Returns the result and the detections
    (for :func:`write_session_outputs`).
    """
    session = Session(Path(root))
    target = load_target(session.target_path)
    cameras = session.camera_names("calibration")
    not_found: list = []
    sizes, stems = {}, {}
    for cam in cameras:
        paths = session.image_paths("calibration", cam)
        if not paths:
            raise FileFormatError(session.root / "calibration" / cam, "no calibration images (needed for the size)")
        img = read_image(next(iter(paths.values())))
        sizes[cam], stems[cam] = (img.shape[1], img.shape[0]), paths
    known = session_intrinsics(session, sizes, model, intrinsics, refine_intrinsics, progress_factory)
    if corners_csv is not None:
        obs = read_corners_csv(corners_csv, sizes, cameras)
    else:
        check_shared_stems(session.root / "calibration", stems)
        n_images = sum(len(session.image_paths("calibration", c)) for c in cameras)
        advance = progress_factory(n_images) if progress_factory else None
        obs, not_found = detect_session(session, target, cameras, advance)
    result = calibrate(obs, target, model, cross_validate=cross_validate, known_intrinsics=known,
                       refine_intrinsics=refine_intrinsics)
    result.not_found = not_found
    return result, obs


def check_shared_stems(folder: Path, paths: dict) -> None:
    """Refuse cameras none of whose image stems another camera has: they can never join the rig.

    Parameters
    ----------
    folder : Path
        The ``calibration`` folder, for the message.
    paths : dict
        ``camera -> {stem: path}`` of every camera's images, in the rig's order.

    Raises
    ------
    FileFormatError
        With two or more cameras, naming those cameras (all but the first when no two cameras share
        a stem) and an image of one of them and of another camera (typically ``right01.jpg``
        beside ``left01.jpg``: the stems must be equal).
    """
    if len(paths) < 2:
        return
    stems = {cam: set(p) for cam, p in paths.items()}
    alone = [cam for cam in paths if not any(stems[cam] & stems[other] for other in paths if other != cam)]
    if not alone:
        return
    joined = [cam for cam in paths if cam not in alone] or alone[:1]
    alone = [cam for cam in alone if cam not in joined]
    cam, other = alone[0], joined[0]
    raise FileFormatError(folder, f"camera graph is disconnected: cameras {alone} share no shot with cameras "
                                  f"{joined}, not one image stem ({next(iter(paths[cam].values())).name} in {cam}, "
                                  f"{next(iter(paths[other].values())).name} in {other}): the same stem in every "
                                  f"camera folder is the same instant, e.g. {cam}/000.png and {other}/000.png")


def write_session_outputs(root: str | Path, result: CalibrationResult, obs: Observations, plots: bool = True,
                          command_line: str = "") -> None:
    """Write ``calibration_report/`` and then ``rig.toml`` (atomically) of a solved session."""
    session = Session(Path(root))
    target = result.target
    report = session.root / REPORT_DIR
    report.mkdir(exist_ok=True)
    write_corners_csv(obs, report / "corners.csv")
    write_outliers_csv(result, report / "outliers.csv")
    write_text_atomic(report / "summary.txt", format_summary(result))
    write_summary_json(result, report / "summary.json")
    if plots:
        from scanrig.calibration.plots import write_plots

        write_plots(result, report)
    import scanrig

    metadata = {
        "created_by": f"scanrig {scanrig.__version__}",
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "command": command_line,
        "target_kind": target.kind,
        "rms_px": round(result.bundle.rms_px(), 6),
        "sigma_px": round(result.bundle.sigma_px, 6),
        "n_observations": int(result.bundle.inliers.sum()),
        "n_outliers": len(result.bundle.outliers),
        "world_frame": f"target frame at shot {obs.shot_names[result.init.reference_shot]!r}",
    }
    if result.known_intrinsics:
        metadata["intrinsics_from"] = {name: k.source for name, k in result.known_intrinsics.items()}
    comments = [f"written by scanrig {scanrig.__version__} on {metadata['date']}: {command_line}",
                f"RMS reprojection error {metadata['rms_px']} px over {metadata['n_observations']} points"]
    save_rig(result.rig, session.rig_path, result.camera_info(), metadata, comments)


def intrinsic_folder_cameras(session) -> list[str]:
    """Cameras with a ``calibration_intrinsic/<camera>/`` folder, in rig order (any number of
    them, whatever ``session.toml`` lists; none when the folder is absent).

    Raises
    ------
    FileFormatError
        A folder named after a camera the session's ``calibration/`` does not have.
    """
    folder = session.root / INTRINSIC_STAGE
    if not folder.is_dir():
        return []
    present = {p.name for p in folder.iterdir() if p.is_dir()}
    rig_cameras = session.camera_names("calibration")
    unknown = sorted(present - set(rig_cameras), key=natural_key)
    if unknown:
        raise FileFormatError(folder, f"cameras {unknown} have no calibration/ folder (the session's cameras: "
                                      f"{rig_cameras})")
    return [c for c in rig_cameras if c in present]


def calibrate_intrinsic_folders(session, cameras: list[str], model: str, image_sizes: dict,
                                progress_factory=None) -> dict:
    """Calibrate each camera alone from its ``calibration_intrinsic/<camera>/`` images.

    Parameters
    ----------
    session : scanrig.io.session.Session
    cameras : list of str
        Cameras to calibrate (each has a folder, see :func:`intrinsic_folder_cameras`).
    model : str
        Camera model (:data:`scanrig.calibration.pipeline.CALIBRATION_MODELS`).
    image_sizes : dict
        ``camera name -> (width, height)`` of the rig's calibration images: the intrinsic
        images must have the same size.
    progress_factory : callable, optional
        ``progress_factory(total) -> advance()``, called once for all the images.

    Returns
    -------
    dict
        ``camera name -> KnownIntrinsics`` with the parameters' standard deviations, the
        calibration's views and RMS, and its warnings.

    Raises
    ------
    InputError
        Naming the folder: too few views, no target found, a focal length the views leave open
        (:data:`MAX_FOCAL_SIGMA_FRACTION`), another image size.
    """
    if not cameras:
        return {}
    own_target = session.root / INTRINSIC_STAGE / INTRINSIC_TARGET
    target = load_target(own_target if own_target.is_file() else session.target_path)
    n_images = sum(len(session.image_paths(INTRINSIC_STAGE, c)) for c in cameras)
    advance = progress_factory(n_images) if progress_factory else None
    out = {}
    for name in cameras:
        folder = f"{INTRINSIC_STAGE}/{name}"
        obs, not_found = detect_session(session, target, [name], advance, stage=INTRINSIC_STAGE)
        try:
            result = calibrate(obs, target, model, cross_validate=False)
        except InputError as exc:
            raise InputError(f"{session.root / folder}: intrinsic calibration of {name!r} alone: {exc}") from None
        n_views = len(np.unique(obs.shot))
        _refuse_open_focal(result.rig[name], result.uncertainty.params_std[name], session.root / folder, n_views)
        detail = (f"{n_views} of {n_views + len(not_found)} images with the target, "
                  f"RMS {result.bundle.rms_px():.3f} px")
        known = KnownIntrinsics(result.rig[name], result.uncertainty.params_std[name], folder, detail,
                                tuple(f"{folder} (calibrated alone): {w}" for w in _own_warnings(result, name, folder)))
        out[name] = check_size(known, image_sizes[name])
    return out


def _refuse_open_focal(camera, params_std: np.ndarray, folder: Path, n_views: int) -> None:
    """Raise when a camera calibrated alone leaves its focal length open to more than
    :data:`MAX_FOCAL_SIGMA_FRACTION` of itself (1 sigma): the rig would hold that lens fixed.

    Parameters
    ----------
    camera : Camera
        The camera as calibrated from ``folder``'s ``n_views`` views.
    params_std : (n_params,) float array
        Standard deviation of each of its intrinsic parameters.
    """
    std = dict(zip(camera.param_names, params_std))
    value = dict(zip(camera.param_names, camera.params))
    loose = [f"{p} {value[p]:.0f} ± {std[p]:.0f} px" for p in ("fx", "fy")
             if std[p] > MAX_FOCAL_SIGMA_FRACTION * abs(value[p])]
    if loose:
        raise InputError(f"{folder}: {n_views} views leave the focal length open ({', '.join(loose)}, 1 sigma): "
                         f"add views (the board filling the image, tilted differently each time)")


def _own_warnings(result: CalibrationResult, name: str, folder: str) -> list[str]:
    """The warnings of a camera calibrated alone from ``folder``; that its intrinsics are not
    determined says to add views there (not to calibrate them separately, which this is)."""
    poorly = result.uncertainty.poorly_determined[name]
    generic = undetermined_intrinsics(name, poorly)
    own = undetermined_intrinsics(name, poorly, f"add views to {folder}/ (the board filling the image, tilted "
                                                f"differently each time); the rig holds them fixed as they are "
                                                f"(--refine-intrinsics: only to these sigmas)")
    return [own if w == generic else w for w in result.warnings]


def session_intrinsics(session, image_sizes: dict, model: str, path: str | Path | None = None,
                       refine: bool = False, progress_factory=None) -> dict:
    """Every known intrinsics of a session: from ``path`` (``--intrinsics``) where it has the
    camera, else from the camera's ``calibration_intrinsic/<camera>/`` images.

    Parameters
    ----------
    session : scanrig.io.session.Session
    image_sizes : dict
        ``camera name -> (width, height)`` of the session's calibration images, pixels.
    model : str
        Model of the per-camera calibrations.
    path : str or Path, optional
        See :func:`read_intrinsics_file`; it must name every camera without such a folder.
    refine : bool
        ``--refine-intrinsics`` was asked for: there must be known intrinsics to refine.
    progress_factory : callable, optional
        See :func:`calibrate_intrinsic_folders`.

    Returns
    -------
    dict
        ``camera name -> KnownIntrinsics`` (empty without a file or folders).
    """
    folder_cameras = intrinsic_folder_cameras(session)
    from_file = read_intrinsics_file(path, image_sizes, tuple(folder_cameras)) if path is not None else {}
    if refine and not from_file and not folder_cameras:
        raise InputError(f"--refine-intrinsics needs known intrinsics to refine: give --intrinsics FILE or "
                         f"{INTRINSIC_STAGE}/<camera>/ images in {session.root}")
    own = calibrate_intrinsic_folders(session, [c for c in folder_cameras if c not in from_file], model,
                                      image_sizes, progress_factory)
    return {**own, **from_file}
