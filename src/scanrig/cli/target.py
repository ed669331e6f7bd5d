"""``scanrig target``: print-ready files for a calibration target."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def command(
    action: Annotated[str, typer.Argument(help="What to do: 'print' writes true-scale SVG files.")],
    target_file: Annotated[Path, typer.Argument(help="The target.toml to read, or a session folder: its target.")],
    out: Annotated[Path, typer.Option("--out", help="Folder for the print files (created if absent).")] = Path("."),
):
    """Write print-ready SVG files (true scale, millimetres) for a target.toml.

    Planar targets give board.svg; the cube gives face0.svg .. face5.svg and cube_net.svg.
    Print at 100 % and check the 50 mm scale bar with a ruler.

    Example: scanrig target print demo_session --out prints
    """
    from scanrig.errors import InputError
    from scanrig.io.session import Session
    from scanrig.targets import load_target
    from scanrig.targets.print_files import write_print_files

    if action != "print":
        raise InputError(f"action must be 'print', got {action!r}")
    existing = next(p for p in (out, *out.parents) if p.exists())
    if not existing.is_dir():
        raise InputError(f"--out {out}: expected a folder for the print files, but {existing} is a file")
    target = load_target(Session(target_file).target_path if target_file.is_dir() else target_file)
    for path in write_print_files(target, out):
        typer.echo(str(path))
