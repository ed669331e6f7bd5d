"""``scanrig demo``: the whole method on the built-in scene, end to end, with its accuracy."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def command(
    out: Annotated[Path, typer.Option(
        help="Session folder to write (created if missing; refused if not empty).")] = Path("scanrig-demo"),
    mode: Annotated[str, typer.Option(
        help="Laser mode: stripe (a sweep of laser sheets: a dense cloud and its mesh) or spot (the adaptive "
             "spot scan).")] = "stripe",
    seed: Annotated[int, typer.Option(help="Seed of every random choice; recorded in the outputs.")] = 0,
    frames: Annotated[int | None, typer.Option(
        min=1, help="Frames of the scan: laser sheets (stripe) or the beam budget (spot). "
                    "[default: stripe 100, quick 12; spot 100, quick 80]")] = None,
    workers: Annotated[int, typer.Option(min=1, help="Processes for frame processing and detection.")] = 2,
    quick: Annotated[bool, typer.Option(
        "--quick", help="A small run (4 cube poses; 12 sheets or 80 spot beams) for tests.")] = False,
):
    """Simulate, calibrate, scan, detect, reconstruct, filter, evaluate and report on the default scene.

    Writes a complete session (calibration and scan images, rig.toml, traces.parquet, points.ply,
    surface.ply, mesh.ply, report.html, truth/) and prints a summary with the accuracy against the
    simulator's truth: the RMS distance of all points to the true surface, before and after the
    filter (the figures of scanrig evaluate). A stage that cannot run says so in the table. Exit
    status 1 if a stage failed.
    A folder that is not empty is refused (exit status 2): the demo writes a whole new session.

    Example: scanrig demo --out demo_run --quick --seed 1
    """
    import time

    from rich.console import Console
    from rich.table import Table

    from scanrig.cli.progress import stage_progress
    from scanrig.demo import run_demo
    from scanrig.errors import ScanrigError
    from scanrig.io.session import check_new_session

    check_new_session(out, "scanrig demo", force=False, can_force=False)
    console = Console()
    with stage_progress(console) as progress:
        start = time.perf_counter()
        summary = run_demo(out, mode=mode, seed=seed, quick=quick, frames=frames, workers=workers, progress=progress)
    stages = Table(title=f"scanrig demo: {out}")
    for column in ("stage", "status", "time (s)", "result"):
        stages.add_column(column)
    for s in summary.stages:
        colour = "green" if s.status == "ok" else "red" if s.status.startswith("failed") else "yellow"
        stages.add_row(s.name, f"[{colour}]{s.status}[/{colour}]", f"{s.seconds:.1f}", s.result)
    console.print(stages)
    figures = Table(title="accuracy and counts (computed in this run)")
    figures.add_column("quantity")
    figures.add_column("value", justify="right")
    for name, value in summary.figures():
        figures.add_row(name, value)
    console.print(figures)
    console.print(f"open {out / 'report.html'} in a browser; wall time {time.perf_counter() - start:.1f} s")
    failed = [s.name for s in summary.stages if s.status.startswith("failed")]
    if failed:
        raise ScanrigError(f"demo stages failed: {', '.join(failed)} (see the table above)")
