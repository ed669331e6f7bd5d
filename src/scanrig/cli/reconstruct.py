"""``scanrig reconstruct``: traces seen by several cameras -> points.ply with per-point quality."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer


def command(
    session: Annotated[Path, typer.Argument(help="Session folder with rig.toml and traces.parquet.")],
    rig: Annotated[Optional[Path], typer.Option(
        help="Calibration to use instead of SESSION/rig.toml: a rig.toml or another session folder.")] = None,
    out: Annotated[Optional[Path], typer.Option(help="Output file instead of SESSION/points.ply.")] = None,
    sigma_floor_px: Annotated[float, typer.Option(
        min=0.0, help="Calibration-error floor added in quadrature to every detection's sigma (px).")] = 0.1,
    gate: Annotated[float, typer.Option(
        min=0.5, max=0.999999, help="Probability of the chi-square consistency gate.")] = 0.999,
    min_angle_deg: Annotated[float, typer.Option(min=0.0, help="Smallest triangulation angle (degrees).")] = 1.0,
    keep_ambiguous: Annotated[bool, typer.Option(
        help="Spots: also write the best point of frames the cameras cannot decide (flagged AMBIGUOUS).")] = False,
    single_view: Annotated[bool, typer.Option(
        help="Stripes: add points seen by one camera, intersected with the frame's light plane.")] = True,
    light_plane: Annotated[Optional[Path], typer.Option(
        help="Classic single-camera mode: intersect each stripe point of the plane's camera with this "
             "calibrated light_plane.toml; with SESSION/scan/object_poses.csv (turntable) the points are "
             "written in the object frame.")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the robust light-plane fits; recorded in points.ply.")] = 0,
    max_sigma_mm: Annotated[Optional[float], typer.Option(
        help="Leave out points whose predicted error bound exceeds this, mm; any mode. The bound is the "
             "sigma along the covariance's largest axis; for multi-view stripes, the largest sigma "
             "across the stripe (the surface normal is perpendicular to it). "
             "Default: 0.1 (the accuracy target) for multi-view stripes, no cut for spots.")] = None,
    workers: Annotated[int, typer.Option(
        min=1, help="Worker processes that solve the stripe frames (the points do not depend on it).")] = 1,
):
    """Triangulate the laser traces of a session into points.ply, rejecting reflections.

    In each frame the candidates of all cameras are combined, the largest set of views whose
    lines of sight meet within their uncertainty is kept (views that disagree, e.g. secondary
    reflections, are dropped), frames where two different sets agree equally well are flagged
    and counted, and each point gets its covariance, residual and number of views. Points less
    precise than --max-sigma-mm are left out: with honest sigmas, the cloud's RMS distance to the
    surface is then at most that value.

    Example: scanrig reconstruct demo_session --sigma-floor-px 0.1
    """
    import math
    import shlex
    import sys

    from scanrig.cli.progress import stage_progress
    from scanrig.errors import InputError
    from scanrig.io.session import session_file
    from scanrig.reconstruct.pipeline import reconstruct_session

    if max_sigma_mm is not None and not (math.isfinite(max_sigma_mm) and max_sigma_mm > 0):
        raise InputError(f"--max-sigma-mm must be a finite number > 0, got {max_sigma_mm}")

    rig = None if rig is None else session_file(rig, "rig.toml", "scanrig calibrate")
    command_line = shlex.join(["scanrig", *sys.argv[1:]])
    with stage_progress() as progress:
        summary = reconstruct_session(session, rig_path=rig, out_path=out, sigma_floor_px=sigma_floor_px,
                                      gate_probability=gate, min_angle_deg=min_angle_deg,
                                      keep_ambiguous=keep_ambiguous, single_view=single_view, seed=seed,
                                      light_plane_path=light_plane,
                                      max_sigma_m=None if max_sigma_mm is None else max_sigma_mm * 1e-3,
                                      workers=workers,
                                      comments=(f"command: {command_line}",),
                                      progress=lambda done, total: progress("reconstructing", done, total))
    head = f"{summary['points']} points from {summary['frames']} frames ({summary['mode']}, seed {seed}): "
    if summary["mode"] == "spot":
        detail = (f"{summary['frames_matched']} matched, {summary['frames_ambiguous']} ambiguous (flagged), "
                  f"{summary['frames_no_agreement']} with no agreeing cameras, "
                  f"{summary['frames_too_few_cameras']} seen by fewer than 2 cameras; "
                  f"{summary['n_candidates'] - summary['n_candidates_used']} of {summary['n_candidates']} "
                  f"candidates rejected")
    elif "detections" in summary:
        detail = (f"{summary['detections'] - summary['detections_isolated']} of {summary['detections']} brightest "
                  f"stripe detections intersected with the light plane ({summary['detections_isolated']} isolated "
                  f"from any stripe left out)")
    else:
        detail = (f"{summary['points_multi_view']} multi-view, {summary['points_single_view']} single-view on the "
                  f"light plane; {summary['frames_with_plane']} frames with a plane; "
                  f"{summary['pairs_off_plane']} of {summary['pairs']} epipolar pairs off the plane (rejected)")
    if "points_imprecise" in summary:
        detail += f"; {summary['points_imprecise']} left out with error bound above {summary['max_sigma_mm']:g} mm"
    typer.echo(f"{head}{detail} -> {summary['out']}")
