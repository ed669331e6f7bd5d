"""``scanrig detect``: laser traces of every scan frame into ``traces.parquet``."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import typer


def command(
    session: Annotated[Path, typer.Argument(help="Session folder with scan/<camera>/<frame> images.")],
    mode: Annotated[str | None, typer.Option(
        help="spot or stripe (default: laser_mode of session.toml, else spot).")] = None,
    color: Annotated[str | None, typer.Option(
        help="Laser colour: red, green, blue or grey (default: laser_color of session.toml, else grey).")] = None,
    workers: Annotated[int, typer.Option(help="Worker processes.")] = 1,
    overlay: Annotated[str | None, typer.Option(
        help="Also write overlays/<FRAME>_<camera>.png for this frame stem.")] = None,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Keep traces.parquet and skip frames already in it.")] = False,
    roi: Annotated[str | None, typer.Option(help="Region of interest u0,v0,u1,v1 in pixels (end-exclusive).")] = None,
    k_detect: Annotated[float, typer.Option(help="Detection threshold in noise sigma of the 3x3 box sum.")] = 6.0,
    direction: Annotated[str, typer.Option(
        help="Stripes: scan along rows, columns, or auto (chosen per block). A fixed laser plane "
             "seen steeply (a single-camera scanner) is best scanned along rows.")] = "auto",
    dark: Annotated[str, typer.Option(
        help="Laser-off frame of a frame: its own scan/<camera>/dark/<frame>.<ext>, else the camera's "
             "scan/<camera>/dark.<ext> (file), or where it has neither the median of its scan frames (median: a "
             "laser swept over a fixed scene).")] = "file",
    saturation_level: Annotated[str | None, typer.Option(
        metavar="DN|auto",
        help="Level at which pixels clip, DN, or auto (the default, or saturation_level in session.toml): each "
             "channel's found from the frames. 16-bit files often hold 10- to 14-bit data, which clip below "
             "65535, and a colour camera's white balance can clip a channel below 255.")] = None,
):
    """Detect laser spots or stripes in every scan frame, with sub-pixel centres and their sigma.

    Writes SESSION/traces.parquet (one row per candidate, every candidate, ranked) atomically and
    every 30 s while running; with --resume an interrupted run continues where it stopped. A camera
    whose frames show a laser of another colour or whose laser-off frames were taken at another
    exposure (they are scaled to the frames'), and a frame whose scene itself reaches the clip
    level, are named in one warning line each; no candidate in any frame is an error (exit 2) and
    writes nothing.

    Example: scanrig detect demo_session --mode spot --color red --workers 2 --overlay 00000
    """
    from scanrig.cli.progress import stage_progress
    from scanrig.errors import InputError
    from scanrig.io.session import Session
    from scanrig.laser.overlay import write_overlays
    from scanrig.laser.session_detect import (colour_mismatches, detect_session, exposure_mismatches,
                                              options_from_session)

    roi_box = None
    if roi is not None:
        try:
            roi_box = tuple(int(x) for x in roi.split(","))
        except ValueError:
            roi_box = ()
        if len(roi_box) != 4:
            raise InputError(f"--roi must be four integers u0,v0,u1,v1, got {roi!r}")
    sess = Session(session)
    options = options_from_session(sess, mode, color, roi_box, k_detect, direction, dark,
                                   _saturation_level(saturation_level))
    stage = f"detecting {options.mode}s"
    with stage_progress() as progress, _detector_warnings_as_lines():
        table = detect_session(sess.root, options, workers=workers, resume=resume,
                               progress=lambda done, total: progress(stage, done, total))
    n_frames = sum(len(sess.image_paths("scan", cam)) for cam in sess.camera_names("scan"))
    for line in colour_mismatches(sess.root, options, table) + exposure_mismatches(sess.root):
        typer.echo(f"warning: {line}", err=True)
    if not len(table):
        raise InputError(f"{sess.root / 'scan'}: no {options.color} laser {options.mode} in any of {n_frames} "
                         f"camera frames; {sess.traces_path.name} not written")
    n_with = len(set(zip(table.column("camera").to_pylist(), table.column("frame").to_pylist())))
    typer.echo(f"{len(table)} candidates in {n_frames} camera frames ({n_with} with candidates) "
               f"-> {sess.traces_path}")
    if overlay is not None:
        for path in write_overlays(sess, overlay, table):
            typer.echo(f"overlay: {path}")


@contextmanager
def _detector_warnings_as_lines() -> Iterator[None]:
    """Within the block, print each detector warning (a frame whose scene reaches the clip level,
    :class:`~scanrig.laser.bright_scene.BrightSceneWarning`) as one ``warning: <message>`` line on
    stderr, as they are issued, like the command's other warnings: Python's own format would
    prefix the library's file and line, which tell a user nothing. Other warnings are printed as
    Python prints them."""
    import warnings

    from scanrig.laser.bright_scene import BrightSceneWarning

    with warnings.catch_warnings():
        python_show = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, BrightSceneWarning):
                typer.echo(f"warning: {message}", err=True)
            else:
                python_show(message, category, filename, lineno, file, line)

        warnings.simplefilter("always", BrightSceneWarning)  # also a text this process showed before
        warnings.showwarning = show
        yield


def _saturation_level(text: str | None) -> float | str | None:
    """``--saturation-level``: None, ``"auto"`` or a number of DN (checked by ``DetectOptions``)."""
    from scanrig.errors import InputError

    if text is None or text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise InputError(f"--saturation-level must be a number of DN or 'auto', got {text!r}") from None
