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
    include_ambiguous: Annotated[bool, typer.Option(help="Also count points flagged AMBIGUOUS.")] = False,
    rig: Annotated[Optional[Path], typer.Option(
        help="The rig the points were reconstructed with, when it is not the true one (e.g. scanrig's own "
             "calibration): its world frame is aligned to truth/rig.toml through the camera poses. A rig.toml "
             "or a session folder (its rig.toml).")] = None,
):
    """Print distance statistics of points to the true surface and write a histogram.

    Reports RMS, mean, 95th and 99th percentile, maximum and the fraction of points farther than
    --outlier-mm from the union of the true meshes.

    Example: scanrig evaluate demo_session
    """
    from scanrig.io.session import session_file
    from scanrig.reconstruct.evaluate import distance_statistics, load_truth_surface, save_histogram
    from scanrig.reconstruct.flags import Flag
    from scanrig.reconstruct.points import read_points

    points = session_file(points, "points.ply", "scanrig reconstruct")
    truth = truth if truth is not None else points.parent / "truth"
    cloud, _ = read_points(points)
    if not include_ambiguous:
        cloud = cloud.select((cloud.flags & Flag.AMBIGUOUS) == 0)
    p_world = cloud.p_world
    if rig is not None:
        from scanrig.io.rig_file import load_rig
        from scanrig.reconstruct.evaluate import rig_alignment

        rig = session_file(rig, "rig.toml", "scanrig calibrate")
        p_world = rig_alignment(load_rig(rig), load_rig(truth / "rig.toml")).apply(p_world)
    distance = load_truth_surface(truth)(p_world)
    stats = distance_statistics(distance, outlier_mm * 1e-3)
    histogram = histogram or points.with_name(f"{points.stem}_distances.png")
    save_histogram(distance, histogram)
    typer.echo(
        f"{stats['n_points']} points: RMS {stats['rms_m'] * 1e3:.4f} mm, mean {stats['mean_m'] * 1e3:.4f} mm, "
        f"p95 {stats['p95_m'] * 1e3:.4f} mm, p99 {stats['p99_m'] * 1e3:.4f} mm, max {stats['max_m'] * 1e3:.4f} mm, "
        f"{100 * stats['fraction_beyond']:.3f} % beyond {outlier_mm:g} mm; {_sigma_text(cloud.sigma)} -> {histogram}"
    )


def _sigma_text(sigma_m: np.ndarray) -> str:
    """The cloud's median predicted sigma, or why there is none (surface.ply carries no sigma)."""
    import numpy as np

    finite = sigma_m[np.isfinite(sigma_m)]
    return f"median predicted sigma {np.median(finite) * 1e3:.4f} mm" if len(finite) else "no predicted sigma in the file"
