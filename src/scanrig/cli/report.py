"""``scanrig report``: one self-contained report.html of a session."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def command(
    session: Annotated[Path, typer.Argument(help="Session folder.")],
    out: Annotated[Path | None, typer.Option(help="Output file (default: SESSION/report.html).")] = None,
    max_points: Annotated[int, typer.Option(min=100, help="Most points in the 3-D view (random subsample).")] = 200_000,
    seed: Annotated[int, typer.Option(help="Seed of the 3-D view's subsample; recorded in the report.")] = 0,
):
    """Write a self-contained HTML report: calibration evidence, detections, 3-D cloud, accuracy.

    Uses whatever the session holds (rig.toml, calibration_report/, light_plane.toml,
    scan/object_poses.csv, traces.parquet, points.ply, surface.ply, truth/) and says which parts
    are missing. The page needs no network.

    Example: scanrig report demo_session --max-points 50000 --seed 1
    """
    import numpy as np

    from scanrig.cli.progress import stage_progress
    from scanrig.report import write_report

    with stage_progress() as progress:
        path = write_report(session, out, rng=np.random.default_rng(seed), max_points=max_points,
                            summary=[("report seed", str(seed))],
                            progress=lambda section: progress(f"report: {section}", 0, None))
    typer.echo(f"wrote {path}")
