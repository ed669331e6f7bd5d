"""``scanrig simulate``: render a simulated session folder with its ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def command(
    out: Annotated[Path, typer.Argument(help="Session folder to write (created if missing; refused if not empty).")],
    scene: Annotated[str, typer.Option(help="Built-in scene name or a scene .toml file.")] = "default",
    cameras: Annotated[int, typer.Option(min=1, max=8, help="Number of cameras of the default rig.")] = 3,
    mode: Annotated[str, typer.Option(help="Laser mode: spot or stripe.")] = "spot",
    frames: Annotated[int, typer.Option(min=1, help="Number of laser frames (a pan/tilt raster).")] = 100,
    seed: Annotated[int, typer.Option(help="Random seed (noise, target poses); recorded in the outputs.")] = 0,
    calibration: Annotated[bool, typer.Option(help="Also render calibration target shots.")] = True,
    shots: Annotated[int, typer.Option(min=1, help="Calibration target poses.")] = 12,
    target: Annotated[str, typer.Option(help="Calibration target: cube, chessboard or charuco.")] = "cube",
    light_plane_shots: Annotated[int, typer.Option(min=0, help="Poses of a planar target across a fixed line laser beside the first camera (light_plane/ + calibration/ twins) for calibrate --light-plane.")] = 0,
    workers: Annotated[int, typer.Option(min=1, help="Rendering processes.")] = 2,
    rig: Annotated[str, typer.Option(
        help="arc: --cameras cameras on an arc, the laser swept by a pan-tilt head. turntable: one camera and a "
             "fixed line laser, the object turning by 360/--frames degrees per frame (use --scene turntable; "
             "writes scan/object_poses.csv; --cameras and --mode do not apply).")] = "arc",
    force: Annotated[bool, typer.Option(
        "--force", help="Write into a non-empty folder: replace the files simulate writes, delete nothing.")] = False,
):
    """Simulate a multi-camera laser session (images + truth/) from a virtual rig.

    Writes scan/<camera>/<frame>.png, calibration/<camera>/<shot>.png, target.toml, session.toml
    and truth/ (rig.toml, meshes, frames.csv, laser.csv, target_poses.csv). The same seed gives
    identical files. A folder that is not empty is refused unless --force is given; --force
    replaces only the files simulate writes and names the files it kept. With --rig turntable (--cameras and --mode do not apply): one camera cam0, a
    fixed laser sheet, scan/cam0/dark/<frame>.png (each step's laser-off frame), scan/object_poses.csv,
    light_plane/cam0/<shot>.png (every calibration pose with the laser on), truth/light_plane.toml and
    meshes in the object frame.
    A scene with a colour camera ([camera] color = true, e.g. --scene colour_stripe) writes RGB
    images, .jpg when its jpeg_quality is set.

    Example: scanrig simulate demo_session --scene default --cameras 3 --mode spot --frames 20 --shots 4 --seed 1

    Example: scanrig simulate tt_session --rig turntable --scene turntable --frames 90 --seed 1
    """
    import shlex
    import sys

    import numpy as np

    from scanrig.cli.progress import stage_progress
    from scanrig.errors import InputError
    from scanrig.io.session import check_new_session, first_names, kept_files
    from scanrig.sim.session_writer import simulate_session

    if mode not in ("spot", "stripe"):
        raise InputError(f"--mode must be 'spot' or 'stripe', got {mode!r}")
    if rig not in ("arc", "turntable"):
        raise InputError(f"--rig must be 'arc' or 'turntable', got {rig!r}")
    if rig == "turntable" and light_plane_shots:
        raise InputError("--light-plane-shots is for --rig arc; --rig turntable photographs every calibration "
                         "pose of the cube with the laser on as well (light_plane/cam0/<shot>)")
    existing = check_new_session(out, "scanrig simulate", force)
    provenance = {"seed": seed, "command": shlex.join(["scanrig", *sys.argv[1:]])}
    with stage_progress() as progress:
        if rig == "turntable":
            from scanrig.sim.turntable import simulate_turntable_session

            simulate_turntable_session(out, scene=scene, n_frames=frames, rng=np.random.default_rng(seed),
                                       with_calibration=calibration, n_shots=shots, target_kind=target,
                                       workers=workers, progress=progress, provenance=provenance)
            cameras = 1
        else:
            simulate_session(out, scene=scene, n_cameras=cameras, mode=mode, n_frames=frames,
                             rng=np.random.default_rng(seed), with_calibration=calibration, n_shots=shots,
                             target_kind=target, light_plane_shots=light_plane_shots, workers=workers,
                             progress=progress, provenance=provenance)
    typer.echo(f"wrote {out} ({frames} frames, {cameras} cameras, seed {seed})")
    if existing:
        kept = kept_files(existing)
        typer.echo(f"--force: replaced {len(existing) - len(kept)} of the {len(existing)} files that were in {out}"
                   + (f"; kept {len(kept)} it does not write: {first_names([str(p.relative_to(out)) for p in kept])}"
                      if kept else ""))
