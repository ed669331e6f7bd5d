"""``scanrig calibrate``: calibrate every camera of a session in one joint solve."""

from __future__ import annotations

import itertools
import shlex
import sys
from pathlib import Path
from typing import Annotated

import typer

#: Calibrations drawn from the calibration's covariance to carry its uncertainty into the light
#: plane's (the sigma they give is known to about 11 %).
CALIBRATION_SAMPLES = 40


def command(
    session: Annotated[Path, typer.Argument(help="Session folder with target.toml and calibration/<camera>/<shot> images.")],
    model: Annotated[str, typer.Option(help="Camera model for every camera: opencv4, opencv5 or opencv8.")] = "opencv5",
    corners: Annotated[Path | None, typer.Option(help="Use detections from this CSV (image,camera,point_id,x,y[,weight]) instead of detecting.")] = None,
    cross_validate: Annotated[bool, typer.Option(help="Also calibrate halves of the shots apart (odd/even, two more interleaved splits, first/second half) and compare them with their stated uncertainty.")] = True,
    plots: Annotated[bool, typer.Option(help="Write residual/uncertainty PNGs to calibration_report/.")] = True,
    light_plane: Annotated[bool, typer.Option("--light-plane", help="Also calibrate the fixed laser's plane of every camera with light_plane/<camera>/ images; writes light_plane.toml.")] = False,
    color: Annotated[str | None, typer.Option(help="Laser colour for --light-plane: red, green, blue or grey (default: laser_color of session.toml, else grey).")] = None,
    seed: Annotated[int, typer.Option(help="Random seed of the robust light-plane fit and its calibration samples; recorded in light_plane.toml.")] = 0,
    intrinsics: Annotated[Path | None, typer.Option(help="rig.toml or OpenCV YAML of intrinsics calibrated beforehand (cameras matched by name): held fixed in the joint solve.")] = None,
    refine_intrinsics: Annotated[bool, typer.Option("--refine-intrinsics", help="Refine the known intrinsics (--intrinsics with params_std, or from calibration_intrinsic/) under priors with their sigma instead of holding them fixed.")] = False,
):
    """Calibrate all cameras jointly from target images; write rig.toml and calibration_report/.

    Detects the target of target.toml (chessboard, ChArUco, circle grid or cube) in every image,
    initialises without user input, runs one robust bundle adjustment over all intrinsics and
    poses, and reports RMS, parameter sigmas, rejected outliers and a cross-validation (halves of
    the shots calibrated apart, four splits: three interleaved, and the first half of the shots
    against the second).

    Intrinsics first, then the rig: with --intrinsics FILE (a rig.toml or OpenCV YAML), or for
    each camera with calibration_intrinsic/<camera>/ images (calibrated alone first, with
    calibration_intrinsic/target.toml if present), those intrinsics are held fixed and only the
    poses are solved; --refine-intrinsics refines them under priors with their sigma instead.

    With --light-plane (classic single-camera mode) it then fits the plane of the fixed line
    laser from light_plane/<camera>/<shot> images of the target with the stripe across it (a
    calibration/<camera>/<shot> image of the same stem is the same pose with the laser off), and
    writes light_plane.toml (light_plane_<camera>.toml with several such cameras) in the world
    frame of rig.toml. Nothing is written when a step fails.

    Example: scanrig calibrate demo_session --model opencv4

    Intrinsics example: scanrig calibrate rig_session --intrinsics intrinsics.toml

    Light-plane example, on a simulated one-camera session (scanrig simulate lp_session --cameras 1
    --frames 1 --no-calibration --target chessboard --light-plane-shots 8):
    scanrig calibrate lp_session --light-plane
    """
    from scanrig.calibration.session_calibration import solve_session, write_session_outputs
    from scanrig.calibration.summary import format_summary
    from scanrig.cli.progress import stage_progress

    command_line = "scanrig " + shlex.join(sys.argv[1:])
    laser = _light_plane_inputs(session, color) if light_plane else None
    with stage_progress() as progress:
        def factory(total):
            done = itertools.count(1)
            return lambda: progress("detecting target", next(done), total)

        result, obs = solve_session(session, model=model, corners_csv=corners, cross_validate=cross_validate,
                                    progress_factory=factory, intrinsics=intrinsics,
                                    refine_intrinsics=refine_intrinsics)
    planes = _light_planes(session, result, *laser, seed) if laser else []
    write_session_outputs(session, result, obs, plots, command_line)
    typer.echo(format_summary(result), nl=False)
    for name, known in result.known_intrinsics.items():
        detail = f" ({known.detail})" if known.detail else ""
        typer.echo(f"{name}: intrinsics {'refined from' if refine_intrinsics else 'held fixed at'} {known.source}{detail}")
    typer.echo(f"wrote {Path(session) / 'rig.toml'}")
    for line in _write_light_planes(session, planes, laser[1] if laser else "", seed, command_line, plots):
        typer.echo(line, nl=False)


def _light_plane_inputs(session: Path, color: str | None) -> tuple[dict, str]:
    """``camera -> {stem: path}`` of the light-plane images, and the laser colour; checked before solving."""
    from scanrig.errors import FileFormatError, InputError
    from scanrig.io.session import Session, images_by_stem, natural_key
    from scanrig.laser.image import LASER_COLORS

    sess = Session(session)
    source = "--color" if color else f"laser_color in {sess.root / 'session.toml'}"
    color = color or sess.settings().get("laser_color", "grey")
    if color not in LASER_COLORS:
        raise InputError(f"{source} must be one of {list(LASER_COLORS)}, got {color!r}")
    folder = sess.root / "light_plane"
    cameras = sorted((p for p in folder.iterdir() if p.is_dir()), key=lambda p: natural_key(p.name)) \
        if folder.is_dir() else []
    images = {cam.name: paths for cam in cameras if (paths := images_by_stem(cam))}
    if not images:
        raise FileFormatError(folder, "no light-plane images (light_plane/<camera>/<shot>.png: the target with "
                                      "the laser stripe across it)")
    unknown = sorted(set(images) - set(sess.camera_names("calibration")))
    if unknown:
        raise FileFormatError(folder, f"cameras {unknown} have light-plane images but no calibration/ folder")
    return images, color


def _light_planes(session: Path, result, images: dict, color: str, seed: int) -> list:
    """``(camera, fit, skipped)`` for every camera with light-plane images.

    A light-plane image whose stem names a solved calibration shot takes that shot's pose and its
    image as the dark frame; any other is located by detecting the target in it (PnP). The
    plane's sigma includes the calibration's, from calibrations drawn from its covariance.
    """
    import numpy as np

    from scanrig.calibration.pipeline import locate_target, sample_states, shot_index
    from scanrig.errors import FileFormatError, InputError
    from scanrig.io.session import images_by_stem, read_image
    from scanrig.reconstruct.light_plane_session import LightPlanePose, calibrate_light_plane_images

    out = []
    rng = np.random.default_rng(seed)
    states = sample_states(result, CALIBRATION_SAMPLES, rng)
    for cam_name, paths in images.items():
        camera = result.rig[cam_name]
        laser_off = images_by_stem(Path(session) / "calibration" / cam_name)
        poses, skipped, solved = [], [], {}
        for stem, path in paths.items():
            index = shot_index(result, stem) if stem in laser_off else None
            if index is not None:
                solved[stem] = index
                pose = result.bundle.state.world_from_target[index]
            else:
                pose = locate_target(read_image(path), result.target, camera)
            if pose is None:
                skipped.append(f"{path}: the target was not found, skipped")
                continue
            poses.append(LightPlanePose(stem, path, laser_off.get(stem), pose))
        c = result.rig.names.index(cam_name)
        samples = [(state.cameras[c], {stem: state.world_from_target[i] for stem, i in solved.items()})
                   for state in states]
        try:
            fit, no_stripe = calibrate_light_plane_images(camera, result.target, poses, color, rng, samples)
        except InputError as exc:
            if not skipped or isinstance(exc, FileFormatError):
                raise
            # the images left out here may be why too few poses remain: name them in the same line
            raise InputError("; ".join([str(exc), *skipped])) from None
        out.append((cam_name, fit, skipped + no_stripe))
    return out


def _write_light_planes(session: Path, planes: list, color: str, seed: int, command_line: str,
                        plots: bool) -> list[str]:
    """Write each plane file, its summary and plot; returns the summaries."""
    from scanrig.calibration.pipeline import REPORT_DIR
    from scanrig.io.atomic import write_text_atomic
    from scanrig.reconstruct.light_plane import save_light_plane
    from scanrig.reconstruct.light_plane_report import format_light_plane_summary, write_light_plane_plot

    report = Path(session) / REPORT_DIR
    summaries = []
    for cam_name, fit, skipped in planes:
        name = "light_plane.toml" if len(planes) == 1 else f"light_plane_{cam_name}.toml"
        summary = format_light_plane_summary(fit, cam_name, skipped)
        if plots:
            write_light_plane_plot(fit, cam_name, report / f"light_plane_{cam_name}.png")
        save_light_plane(Path(session) / name, fit.plane, cam_name,
                         comments=(f"{command_line} (seed {seed})",
                                   f"{int(fit.inliers.sum())} stripe points of {len(fit.poses)} poses, "
                                   f"RMS {1e3 * fit.plane.residual_m:.4f} mm"),
                         extra={"n_poses": len(fit.poses), "laser_color": color})
        summaries.append(summary + f"wrote {Path(session) / name}\n")
    if planes:
        write_text_atomic(report / "light_plane_summary.txt", "".join(summaries))
    return summaries
