"""``scanrig calibrate``: calibrate every camera of a session in one joint solve."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Annotated

import typer


def command(
    session: Annotated[Path, typer.Argument(help="Session folder with target.toml and calibration/<camera>/<shot> images.")],
    model: Annotated[str, typer.Option(help="Camera model for every camera: opencv4, opencv5 or opencv8.")] = "opencv5",
    corners: Annotated[Path | None, typer.Option(help="Use detections from this CSV (image,camera,point_id,x,y[,weight]) instead of detecting.")] = None,
    cross_validate: Annotated[bool, typer.Option(help="Also calibrate odd and even shots apart and compare.")] = True,
    plots: Annotated[bool, typer.Option(help="Write residual/uncertainty PNGs to calibration_report/.")] = True,
):
    """Calibrate all cameras jointly from target images; write rig.toml and calibration_report/.

    Detects the target of target.toml (chessboard, ChArUco, circle grid or cube) in every image,
    initialises without user input, runs one robust bundle adjustment over all intrinsics and
    poses, and reports RMS, parameter sigmas, rejected outliers and an odd/even cross-validation.

    Example: scanrig calibrate demo_session --model opencv5
    """
    from rich.progress import Progress

    from scanrig.calibration.pipeline import calibrate_session
    from scanrig.calibration.summary import format_summary

    with Progress(transient=True) as progress:
        def factory(total):
            task = progress.add_task("detecting target", total=total)
            return lambda: progress.advance(task)

        result = calibrate_session(session, model=model, corners_csv=corners, cross_validate=cross_validate,
                                   plots=plots, command_line="scanrig " + shlex.join(sys.argv[1:]),
                                   progress_factory=factory)
    typer.echo(format_summary(result), nl=False)
    typer.echo(f"wrote {Path(session) / 'rig.toml'}")
