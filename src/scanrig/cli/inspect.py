"""``scanrig inspect``: compare a scan with the part's CAD model (deviation map, pass/fail)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def command(
    cloud: Annotated[Path, typer.Argument(help="The scan: a PLY of points or a mesh (its vertices are used), metres; "
                                               "or a session folder: its surface.ply (the points the filter kept) "
                                               "if present, else its points.ply.")],
    cad: Annotated[Path, typer.Option("--cad", help="The part's CAD model: STL, PLY or OBJ triangles.")],
    out: Annotated[Path, typer.Option("--out", help="Output folder for inspection.ply, .json and .html.")],
    tolerance_mm: Annotated[float, typer.Option("--tolerance-mm", help="Tolerance on |deviation|, mm.")] = 0.1,
    cad_units: Annotated[str, typer.Option("--cad-units", help="Unit of the CAD file: m or mm.")] = "m",
    no_align: Annotated[bool, typer.Option("--no-align", help="The cloud is already in the CAD frame (after "
                                                              "--initial when given): do not align.")] = False,
    initial: Annotated[Path | None, typer.Option("--initial", help="Text file with a 4x4 rigid cad_from_cloud "
                                                                   "(metres) to start from, instead of the "
                                                                   "global coarse alignment.")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Random seed (recorded in the outputs).")] = 0,
):
    """Align a scan to its CAD model and map the signed deviation of every point.

    A global coarse alignment (no hand placing) and a robust point-to-plane ICP put the cloud in
    the CAD frame; each point's deviation is its distance to the CAD surface, positive outside
    the material. Writes DIR/inspection.ply (aligned points, deviation_m, colour),
    DIR/inspection.json (transform, statistics, alignment residual, worst regions) and
    DIR/inspection.html (3-D deviation map, histogram, table, worst regions).

    Example: scanrig inspect demo_session --cad demo_session/truth/meshes/steps.ply --out demo_inspection --no-align --tolerance-mm 0.5
    """
    import numpy as np

    from scanrig.cli.progress import stage_progress
    from scanrig.errors import FileFormatError, InputError
    from scanrig.inspect import (
        AlignmentError,
        inspect_cloud,
        load_cad,
        write_inspection,
    )
    from scanrig.inspect.cad import check_cad_scale
    from scanrig.inspect.outputs import check_outputs_free
    from scanrig.report.inspection_page import write_inspection_page

    if not tolerance_mm > 0:
        raise InputError(f"--tolerance-mm must be > 0, got {tolerance_mm}")
    check_outputs_free(out)
    cloud_path, points = _read_cloud(cloud)
    if len(points) == 0:
        raise InputError(f"{cloud_path}: the cloud is empty (no vertices)")
    if not np.all(np.isfinite(points)):
        raise FileFormatError(cloud_path, "holds non-finite coordinates")
    start = _read_initial(initial) if initial is not None else None
    mesh = load_cad(cad, cad_units)
    check_cad_scale(mesh, points, str(cad))
    with stage_progress() as progress:
        progress(f"inspecting {len(points)} points of {cloud_path} against {cad}", 0, None)
        try:
            inspection = inspect_cloud(points, mesh, tolerance_m=tolerance_mm * 1e-3, align=not no_align,
                                       initial_cad_from_cloud=start, seed=seed)
        except AlignmentError as exc:
            raise InputError(f"{cloud_path}: {exc}") from None
    title = f"scanrig inspect {cloud_path} --cad {cad} --tolerance-mm {tolerance_mm:g} --seed {seed}"
    # The page first: drawing it is the step most likely to fail, and then no file is written.
    write_inspection_page(inspection, out, points_m=points, title=title)
    write_inspection(inspection, out, points_m=points, title=title)
    s = inspection.stats
    typer.echo(f"{s.n_points} points of {cloud_path}: {100 * s.within_tolerance:.1f} % within ±{tolerance_mm:g} mm, "
               f"RMS {1e3 * s.rms_m:.4f} mm, largest {1e3 * s.max_abs_m:.4f} mm; wrote {out}/inspection.ply, "
               f".json and .html")
    for warning in inspection.warnings:
        typer.echo(f"warning: {warning}", err=True)


def _read_cloud(cloud: Path):
    """The cloud's file and its ``(N, 3)`` points: a PLY, or a session's surface.ply (kept points) or points.ply."""
    import numpy as np

    from scanrig.errors import FileFormatError
    from scanrig.io.ply import XYZ, read_ply, read_points
    from scanrig.io.session import session_file

    if cloud.is_dir() and (cloud / "surface.ply").is_file():
        vertices, _, _ = read_ply(cloud / "surface.ply")
        keep = vertices["inlier"] != 0 if "inlier" in vertices else slice(None)
        return cloud / "surface.ply", np.column_stack([vertices[k][keep].astype(np.float64) for k in XYZ])
    path = session_file(cloud, "points.ply", "scanrig reconstruct")
    if path.suffix.lower() != ".ply":
        raise FileFormatError(path, f"expected a PLY cloud or a session folder, got suffix {path.suffix!r}")
    return path, read_points(path)


def _read_initial(path: Path):
    """A 4x4 rigid transform from a text file (whitespace-separated rows)."""
    import numpy as np

    from scanrig.errors import FileFormatError, ShapeError
    from scanrig.geometry.transform import RigidTransform

    try:
        matrix = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as exc:
        raise FileFormatError(path, f"--initial: not a readable 4x4 matrix ({exc})") from None
    try:
        return RigidTransform.from_matrix(matrix).as_matrix()
    except ShapeError as exc:
        raise FileFormatError(path, f"--initial: {exc}") from None
