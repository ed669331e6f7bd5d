"""``scanrig evaluate``: distance statistics of a point cloud to the simulator's true surface."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer


def command(
    points: Annotated[Path, typer.Argument(help="points.ply written by scanrig reconstruct (or any cloud PLY), or "
                                                "a session folder: its points.ply.")],
    truth: Annotated[Optional[Path], typer.Option(
        help="The simulator's truth/ folder (meshes/*.ply). [default: truth/ beside POINTS]")] = None,
    histogram: Annotated[Optional[Path], typer.Option(
        help="Histogram PNG to write (default: next to POINTS, <stem>_distances.png).")] = None,
    outlier_mm: Annotated[float, typer.Option(min=0.0, help="Distance counted as an outlier (mm).")] = 1.0,
    rig: Annotated[Optional[Path], typer.Option(
        help="The rig the points were reconstructed with, when it is not the true one (e.g. scanrig's own "
             "calibration): its world frame is tied to truth/rig.toml through the camera poses, unless its "
             "[metadata] world_frame is \"scene\" (the demo's rig.toml). A rig.toml or a session folder "
             "(its rig.toml).")] = None,
):
    """Print the accuracy of a cloud against the true surface and write a histogram.

    The accuracy is the RMS of the distances of every point of POINTS to the union of the true
    meshes (also mean, 95th and 99th percentile, maximum, and the share beyond --outlier-mm).
    When POINTS is a session's points.ply and the session has the filter's surface.ply, the same
    figures follow for the points the filter kept, with the number it removed. Then the coverage:
    the share of the true surface in the cloud's bounding box within 5 mm of a point. These are
    the figures scanrig demo prints and report.html shows. Each step (loading the true meshes,
    measuring, writing the histogram) shows a progress bar, or a line when it starts and ends when
    stdout is not a terminal.

    Example: scanrig evaluate demo_session
    """
    import math

    from scanrig.cli.progress import stage_progress
    from scanrig.io.session import session_file
    from scanrig.reconstruct.evaluate import load_truth_surface, save_histogram, session_accuracy

    points = session_file(points, "points.ply", "scanrig reconstruct")
    truth = truth if truth is not None else points.parent / "truth"
    if rig is not None:
        rig = session_file(rig, "rig.toml", "scanrig calibrate")
    surface = points.with_name("surface.ply") if points.name == "points.ply" else None
    histogram = histogram or points.with_name(f"{points.stem}_distances.png")
    with stage_progress() as progress:
        progress(f"loading the true surface ({truth})", 0, None)
        true_surface = load_truth_surface(truth)
        progress(f"measuring {points} and its coverage", 0, None)
        accuracy = session_accuracy(points, truth, rig_path=rig, surface_path=surface, outlier_m=outlier_mm * 1e-3,
                                    truth=true_surface)
        progress("writing the histogram", 0, None)
        save_histogram(accuracy.distance_m, histogram)
    first, *rest = accuracy.lines()
    sigma = accuracy.median_sigma_m
    sigma_text = "no predicted sigma in the file" if math.isnan(sigma) else f"median predicted sigma {sigma * 1e3:.4f} mm"
    typer.echo(f"{first}; {sigma_text} -> {histogram}")
    for line in rest:
        typer.echo(line)
