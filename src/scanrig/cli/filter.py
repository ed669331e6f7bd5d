"""``scanrig filter``: robust neural surface filter of a point cloud."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

#: The filter's summary, written beside ``surface.ply``.
SUMMARY_NAME = "filter_summary.json"


def command(
    points: Annotated[Path, typer.Argument(help="Input PLY (its vertices need x, y, z, float32 or float64, in "
                                                "metres), or a session folder: its points.ply.")],
    q: Annotated[float, typer.Option("--q", help="Tolerated fraction of bad data, in (0, 0.5].")] = 0.25,
    seed: Annotated[int, typer.Option("--seed", help="Random seed (recorded in the outputs).")] = 0,
    device: Annotated[str, typer.Option("--device", help="Torch device: cpu, cuda or auto.")] = "cpu",
    architecture: Annotated[str, typer.Option("--architecture", help="'mlp' (tanh, 2 hidden layers) or 'ridge' (one layer of s(ax+by+c) units).")] = "mlp",
    max_chart_points: Annotated[int, typer.Option("--max-chart-points", help="Largest number of points per chart.")] = 4096,
    sigma_floor_mm: Annotated[float, typer.Option("--sigma-floor-mm", help="Known sensor noise in mm; the noise scale never goes below it, and sparse points are judged against it.")] = 0.0,
):
    """Reject gross errors and denoise a point cloud with a robust neural surface fit.

    Writes, beside the input (in the session folder when given one), surface.ply (one vertex per
    input point, in input order: x, y, z = denoised position, inlier 0/1, score, residual in
    metres), mesh.ply (the fitted surface) and filter_summary.json (points removed, residual RMS
    over the kept points and over all of them, how far denoising moved them).

    Example: scanrig filter demo_session --q 0.25 --seed 1
    """
    import json

    import numpy as np

    from scanrig.cli.progress import stage_progress
    from scanrig.errors import InputError
    from scanrig.io.atomic import write_text_atomic
    from scanrig.io.filter_files import write_filter_files
    from scanrig.io.ply import read_points_with_sigma
    from scanrig.io.session import session_file
    from scanrig.surface.filter import filter_points
    from scanrig.surface.hampel import check_q
    from scanrig.surface.meshing import mesh_from_result
    from scanrig.surface.fit_settings import FitSettings

    check_q(q)
    if sigma_floor_mm < 0:
        raise InputError(f"--sigma-floor-mm must be >= 0, got {sigma_floor_mm}")
    points = session_file(points, "points.ply", "scanrig reconstruct")
    xyz, point_sigma = read_points_with_sigma(points)
    if len(xyz) == 0:
        raise InputError(f"{points}: the vertex element is empty")
    settings = FitSettings(q=q, architecture=architecture, depth=1 if architecture == "ridge" else 2)
    with stage_progress() as progress:
        progress(f"filtering {len(xyz)} points", 0, None)
        result = filter_points(xyz, rng=np.random.default_rng(seed), q=q, settings=settings,
                               max_chart_points=max_chart_points, sigma_floor=sigma_floor_mm * 1e-3,
                               device=device, point_sigma=point_sigma)
        mesh_vertices, faces = mesh_from_result(result)
    header = [f"scanrig filter {points.name} --q {q} --seed {seed} --device {device} "
              f"--architecture {architecture} --max-chart-points {max_chart_points}",
              f"seed {seed}", "units m"]
    surface_path, mesh_path = write_filter_files(points.parent, result, mesh_vertices, faces, header)
    summary = result.summary()
    summary_path = points.parent / SUMMARY_NAME
    write_text_atomic(summary_path, json.dumps({"command": header[0], "seed": seed, **summary}, indent=2) + "\n")
    typer.echo(f"{len(xyz) - summary['n_removed']} of {len(xyz)} points kept, {summary['n_removed']} removed "
               f"({len(result.charts)} charts, {summary['n_sparse']} points judged as sparse); residual RMS "
               f"{summary['rms_residual_inliers_m'] * 1e3:.4f} mm over the kept points, "
               f"{summary['rms_residual_all_m'] * 1e3:.4f} mm over all; denoising moved all points by "
               f"{summary['rms_denoised_shift_all_m'] * 1e3:.4f} mm RMS; wrote {surface_path}, {mesh_path} "
               f"({len(faces)} triangles) and {summary_path}")
