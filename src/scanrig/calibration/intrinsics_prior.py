"""Intrinsics first, then the rig: intrinsics known before the joint solve.

Two sources, matched to the session's cameras by name:

- a file given with ``scanrig calibrate --intrinsics FILE``: a scanrig ``rig.toml`` (its
  ``params_std``, when present, are the intrinsics' standard deviations) or an OpenCV FileStorage
  YAML (:mod:`scanrig.io.opencv_yaml`; no standard deviations);
- a separate calibration of each camera alone from ``calibration_intrinsic/<camera>/`` images
  (any target: ``calibration_intrinsic/target.toml`` when present, else the session's target;
  :func:`scanrig.calibration.session_calibration.calibrate_intrinsic_folders`).

The joint solve then holds those intrinsics fixed, or, with ``refine`` (``--refine-intrinsics``),
refines them under Gaussian priors with their standard deviations
(:func:`scanrig.calibration.bundle.bundle_adjust`'s ``priors``). Only the rig poses are then
left to the rig's views, which is what a rig whose views cannot fix the intrinsics needs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError, InputError
from scanrig.geometry.camera import PINHOLE_PARAMS, Camera

#: Session sub-folder with each camera's own intrinsic calibration images.
INTRINSIC_STAGE = "calibration_intrinsic"
#: Optional target file of those images, inside :data:`INTRINSIC_STAGE`.
INTRINSIC_TARGET = "target.toml"
#: A refined parameter this many prior sigmas from its prior is warned about: when prior and views
#: describe the same lens, the refined value differs from the prior by at most the prior's sigma
#: (one standard deviation), so each parameter exceeds 3 with probability under 0.3 %.
PRIOR_PULL_SIGMAS = 3.0


@dataclass(frozen=True)
class KnownIntrinsics:
    """One camera's intrinsics from outside the rig's views.

    Attributes
    ----------
    camera : Camera
        Model, parameters and image size (its pose is not used).
    params_std : ndarray of shape (n_params,) or None
        Standard deviation of each parameter (0 = held fixed where it came from); None when the
        source gives none.
    source : str
        Where they came from (a file, or ``calibration_intrinsic/<camera>``), for messages.
    detail : str
        How they were obtained, for the summary (views and RMS of a camera's own calibration).
    warnings : tuple of str
        The warnings of that calibration, each naming its folder.
    """

    camera: Camera
    params_std: np.ndarray | None
    source: str
    detail: str = ""
    warnings: tuple[str, ...] = ()


def read_intrinsics_file(path: str | Path, image_sizes: dict, optional: tuple[str, ...] = ()) -> dict:
    """The intrinsics of a ``rig.toml`` or OpenCV YAML, matched to the session's cameras by name.

    Parameters
    ----------
    path : str or Path
        ``.toml`` (a scanrig rig file) or ``.yml``/``.yaml`` (OpenCV FileStorage). A one-camera
        OpenCV calibration file without a ``name`` node matches a session of one camera.
    image_sizes : dict
        ``camera name -> (width, height)`` of the session's calibration images, pixels.
    optional : tuple of str
        Cameras the file may leave out (their intrinsics come from elsewhere).

    Returns
    -------
    dict
        ``camera name -> KnownIntrinsics`` for every session camera in the file.

    Raises
    ------
    FileFormatError
        An unreadable file, a camera the session does not have, a session camera the file lacks
        (outside ``optional``), another image size, or ``params_std`` of the wrong length.
    """
    from scanrig.io.opencv_yaml import import_opencv_yaml
    from scanrig.io.rig_file import load_rig_info

    path = Path(path)
    names = list(image_sizes)
    suffix = path.suffix.lower()
    if suffix == ".toml":
        rig, info, _ = load_rig_info(path)
        std = {name: info[name].get("params_std") for name in rig.names}
    elif suffix in (".yml", ".yaml"):
        rig = import_opencv_yaml(path, name=names[0] if len(names) == 1 else None)
        std = dict.fromkeys(rig.names)
    else:
        raise FileFormatError(path, f"intrinsics file must be a rig.toml (.toml) or OpenCV YAML (.yml, .yaml), "
                                    f"got {suffix or 'no suffix'!r}")
    unknown = [n for n in rig.names if n not in image_sizes]
    missing = [n for n in names if n not in rig.names and n not in optional]
    if unknown or missing:
        parts = ([f"cameras {unknown} are not in the session (its cameras: {names})"] if unknown else []) + \
                ([f"session cameras {missing} are missing from it"] if missing else [])
        raise FileFormatError(path, "intrinsics matched by camera name: " + "; ".join(parts))
    out = {}
    for cam in rig.cameras:
        params_std = None if std[cam.name] is None else np.asarray(std[cam.name], dtype=float)
        if params_std is not None and (params_std.shape != cam.params.shape or np.any(~(params_std >= 0))):
            raise FileFormatError(path, f"camera {cam.name!r}: params_std must be {len(cam.params)} values >= 0 "
                                        f"(one per parameter of {cam.model}), got {std[cam.name]!r}")
        out[cam.name] = check_size(KnownIntrinsics(cam, params_std, str(path)), image_sizes[cam.name])
    return out


def check_size(known: KnownIntrinsics, size: tuple[int, int]) -> KnownIntrinsics:
    """``known`` itself when its image size is ``size`` (width, height); else InputError."""
    cam = known.camera
    if (cam.width, cam.height) != tuple(size):
        raise InputError(f"{known.source}: camera {cam.name!r} was calibrated at {cam.width}x{cam.height} but its "
                         f"calibration images are {size[0]}x{size[1]}; intrinsics hold for one image size only")
    return known


def solve_constraints(known: dict, refine: bool) -> tuple[dict, dict]:
    """How known intrinsics enter the bundle adjustment.

    Parameters
    ----------
    known : dict
        ``camera name -> KnownIntrinsics``.
    refine : bool
        Refine them under priors (needs ``params_std``) instead of holding them fixed.

    Returns
    -------
    fixed_params : dict
        ``camera name -> parameter names held fixed`` (all of them without ``refine``; with it,
        those whose standard deviation is 0).
    priors : dict
        ``camera name -> (params, params_std)`` (empty without ``refine``).

    Raises
    ------
    InputError
        ``refine`` for intrinsics that come without standard deviations.
    """
    if not refine:
        return {name: k.camera.param_names for name, k in known.items()}, {}
    lacking = sorted({k.source for k in known.values() if k.params_std is None})
    if lacking:
        raise InputError(f"--refine-intrinsics needs the intrinsics' standard deviations, and {', '.join(lacking)} "
                         "has none (a rig.toml with params_std has them); leave out --refine-intrinsics to hold "
                         "them fixed")
    fixed = {name: tuple(p for p, s in zip(k.camera.param_names, k.params_std) if s == 0) for name, k in known.items()}
    return fixed, {name: (k.camera.params, k.params_std) for name, k in known.items()}


def with_known_intrinsics(cameras: list[Camera], known: dict) -> list[Camera]:
    """``cameras`` (poses kept) with the intrinsics of ``known`` where it has them."""
    out = []
    for cam in cameras:
        k = known.get(cam.name)
        out.append(cam if k is None else
                   Camera(cam.name, k.camera.model, k.camera.params, cam.width, cam.height, cam.cam_from_world))
    return out


def undetermined_intrinsics(camera: str, poorly_determined: list, advice: str | None = None) -> str | None:
    """The one-line warning for a camera whose views leave its focal length or principal point open,
    or None.

    Parameters
    ----------
    camera : str
    poorly_determined : list of (parameter, std, moved_px)
        The parameters whose 1 sigma moves some pixel of the image by more than
        :data:`scanrig.calibration.uncertainty.POORLY_DETERMINED_PX`
        (:attr:`scanrig.calibration.uncertainty.Uncertainty.poorly_determined`).
    advice : str, optional
        What to do, ending the line; default: calibrate the intrinsics separately.

    Returns
    -------
    str or None
        ``"cam1: intrinsics not determined by these views (fx ±11 px, cx ±10 px): ..."`` (the
        pinhole parameters in their order), or None.
    """
    std = {p: s for p, s, _ in poorly_determined}
    loose = [f"{p} ±{std[p]:.2g} px" for p in PINHOLE_PARAMS if p in std]
    if not loose:
        return None
    advice = advice or f"calibrate them separately ({INTRINSIC_STAGE}/{camera}/ images, or --intrinsics FILE)"
    return f"{camera}: intrinsics not determined by these views ({', '.join(loose)}): {advice}"


def prior_pull_warning(camera: Camera, known: KnownIntrinsics) -> str | None:
    """The one-line warning for intrinsics refined far from their prior (a prior from another
    camera, focus or zoom), or None.

    Parameters
    ----------
    camera : Camera
        The camera as refined under the prior.
    known : KnownIntrinsics
        Its prior (``params_std`` 0: held fixed, not judged).
    """
    std = known.params_std
    z = np.divide(camera.params - known.camera.params, std, out=np.zeros(len(std)), where=std > 0)
    k = int(np.argmax(np.abs(z)))
    if abs(z[k]) <= PRIOR_PULL_SIGMAS:
        return None
    return (f"{camera.name}: these views pull its intrinsics {abs(z[k]):.1f} sigma from {known.source} "
            f"({camera.param_names[k]} {known.camera.params[k]:.6g} -> {camera.params[k]:.6g}): check that they "
            "are this camera's at this focus and zoom, or calibrate it again")
