"""``scanrig relocate``: re-estimate one moved camera's pose from known world points."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def command(
    session: Annotated[Path, typer.Argument(help="Session folder with rig.toml.")],
    camera: Annotated[str, typer.Option(help="Name of the camera that moved.")],
    points: Annotated[Path, typer.Option(help="CSV with columns point,x,y,z,u,v (world metres, pixels in that camera).")],
    sigma_px: Annotated[float | None, typer.Option(help="Pixel noise of the u,v for the uncertainty; default measured from the fit.")] = None,
    force: Annotated[bool, typer.Option(
        "--force", help="Update rig.toml even when the change is within 3 sigma (not significant).")] = False,
):
    """Re-estimate a moved camera's pose from >= 5 known points; update rig.toml if it moved.

    Intrinsics stay as calibrated. Prints the pose change and its uncertainty and whether the
    change is significant (> 3 sigma). rig.toml is rewritten (atomically) only when the camera
    moved, or with --force; otherwise it is left as it was.

    Example: scanrig relocate demo_session --camera cam1 --points demo_session/survey/cam1.csv
    """
    import datetime

    from scanrig.calibration.relocate import read_known_points, relocate_camera
    from scanrig.errors import InputError
    from scanrig.io.rig_file import load_rig_info, save_rig
    from scanrig.io.session import Session

    sess = Session(session)
    rig, info, metadata = load_rig_info(sess.rig_path)
    if camera not in rig:
        raise InputError(f"--camera {camera!r} is not in {sess.rig_path}; cameras are {rig.names}")
    _, xyz, uv = read_known_points(points)
    result = relocate_camera(rig[camera], xyz, uv, sigma_px)
    std_mm = result.center_std_m * 1000.0
    typer.echo(f"{camera}: centre moved {result.shift_m * 1000:.3f} mm (new centre sigma "
               f"[{std_mm[0]:.3f}, {std_mm[1]:.3f}, {std_mm[2]:.3f}] mm), rotated {result.rotation_deg:.4f} deg "
               f"(sigma {result.rotation_std_deg:.4f} deg per axis); RMS {result.rms_px:.3f} px, "
               f"sigma {result.sigma_px:.3f} px")
    typer.echo("camera moved: " + ("yes (change > 3 sigma)" if result.moved else "no (change within 3 sigma)"))
    if not (result.moved or force):
        typer.echo(f"{sess.rig_path} left unchanged (--force updates it anyway)")
        return
    metadata = dict(metadata)
    stamp = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    metadata[f"relocated_{camera}"] = (f"{stamp}: from {points.name}, shift {result.shift_m * 1000:.3f} mm, "
                                       f"rotation {result.rotation_deg:.4f} deg")
    save_rig(rig.replace_camera(result.camera), sess.rig_path, info, metadata,
             comments=[f"camera {camera} relocated by scanrig relocate on {stamp}"])
    typer.echo(f"updated {sess.rig_path}" + ("" if result.moved else " (--force: the change is not significant)"))
