"""``scanrig export``: a session's clouds, meshes or calibration in other tools' formats."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def command(
    session: Annotated[Path, typer.Argument(help="Session folder (rig.toml, points.ply, surface.ply, mesh.ply).")],
    fmt: Annotated[str, typer.Option("--format", help="ply, ply-ascii, stl, obj (geometry) or "
                                                       "opencv-yaml, mrcal, colmap (calibration).")] = "ply",
    out: Annotated[Path | None, typer.Option(help="Output folder (default: SESSION/export/<format>).")] = None,
):
    """Export clouds and meshes (PLY, STL, OBJ) or the calibration (OpenCV YAML, mrcal, COLMAP).

    Geometry formats convert each of points.ply, surface.ply and mesh.ply that exists (STL:
    meshes only); calibration formats convert rig.toml. Coordinates stay in metres, world frame.

    Example: scanrig export demo_session --format obj --out demo_export
    """
    from scanrig.exports import export_session

    out_dir = out if out is not None else Path(session) / "export" / fmt
    for path in export_session(session, fmt, out_dir):
        typer.echo(f"wrote {path}")
