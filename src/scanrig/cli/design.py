"""``scanrig design``: where to put the cameras, and what accuracy the rig will reach."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Annotated

import typer


def command(
    out: Annotated[Path, typer.Option(
        "--out", help="Folder for rig.toml, coverage.ply/.png, cameras.csv, design.toml.")],
    mesh: Annotated[Path | None, typer.Option(
        "--mesh", help="The object: a mesh file (STL, PLY, OBJ...), metres.")] = None,
    scene: Annotated[str | None, typer.Option(
        "--scene", help="The object: a simulator scene, built-in name (e.g. default, ibeam) or .toml; "
                        "its floor only occludes.")] = None,
    cameras: Annotated[int, typer.Option("--cameras", help="Number of cameras to place.")] = 3,
    spec: Annotated[Path | None, typer.Option(
        "--spec", help="Design TOML: cameras, mounting region, laser, target.")] = None,
    rig: Annotated[Path | None, typer.Option(
        "--rig", help="Analyse this rig.toml (or a session folder's) instead of designing one.")] = None,
    ring: Annotated[bool, typer.Option(
        "--ring/--no-ring", help="Also analyse a symmetric ring for comparison.")] = True,
    allow_open: Annotated[bool, typer.Option("--allow-open", help="Accept a one-sided mesh (sheet, partial scan) "
                                             "whose back faces cameras see.")] = False,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the surface sampling of big meshes.")] = 0,
):
    """Choose camera poses and lenses for an object and predict coverage and accuracy.

    Prints a table per camera with its marginal gain and the covered fraction of the surface
    (seen by two or more cameras within the accuracy target), against a symmetric ring of the
    same cameras. The rig file loads with scanrig.load_rig; the simulator renders it
    (scanrig.sim.simulate_session(..., rig=...)).

    Example: scanrig design --scene ibeam --cameras 3 --out design
    """
    import numpy as np
    import trimesh
    from rich.console import Console

    import scanrig
    from scanrig.cli.progress import stage_progress
    from scanrig.design import analyze_existing, design_rig, load_spec
    from scanrig.design.outputs import camera_rows, design_summary, write_design
    from scanrig.design.spec import DesignSpec
    from scanrig.errors import FileFormatError, InputError
    from scanrig.io.rig_file import load_rig
    from scanrig.io.session import session_file

    if (mesh is None) == (scene is None):
        raise InputError("give exactly one of --mesh FILE or --scene NAME")
    if mesh is not None:
        try:
            obj = trimesh.load_mesh(mesh, force="mesh")
        except Exception as exc:  # noqa: BLE001 - trimesh raises many types for unreadable files
            raise FileFormatError(mesh, f"not a readable mesh: {exc}") from None
        name, occluders = str(mesh), ()
    else:
        (obj, occluders), name = scene_meshes(scene), f"scene {scene!r}"
    design_spec = load_spec(spec) if spec is not None else DesignSpec()
    provenance = {"scanrig": scanrig.__version__, "command": shlex.join(["scanrig", *sys.argv[1:]]),
                  "object": name, "seed": seed}
    with stage_progress(Console(stderr=True)) as progress:
        if rig is not None:
            existing = load_rig(session_file(rig, "rig.toml", "scanrig calibrate"))
            progress("analysing the rig", 0, 1)
            design = analyze_existing(obj, existing, design_spec, mesh_name=name, occluders=occluders)
            progress("analysing the rig", 1, 1)
        else:
            design = design_rig(obj, cameras, design_spec, np.random.default_rng(seed), mesh_name=name,
                                allow_open=allow_open, compare_ring=ring, occluders=occluders,
                                progress=lambda done, total: progress("rating candidate cameras", done, total))
        progress("writing outputs", 0, None)
        paths = write_design(out, design, provenance)

    out_console = Console()
    out_console.print(camera_table(camera_rows(design), f"{name}: {len(design.rig)} cameras, target sigma "
                                                      f"{1e3 * design.spec.target.sigma_m:.3g} mm"))
    summary = design_summary(design)
    out_console.print(f"covered within target: {100 * summary['covered_fraction']:.1f} % of the surface; "
                      f"median sigma {1e3 * summary['sigma_median_m']:.3g} mm, "
                      f"speckle floor {1e3 * summary['speckle_floor_median_m']:.3g} mm")
    if "ring_covered_fraction" in summary:
        out_console.print(f"symmetric ring of the same cameras: {100 * summary['ring_covered_fraction']:.1f} %")
    for path in paths:
        out_console.print(str(path))


#: Columns of the camera table: header (unit on its own line), key of ``camera_rows``, format. Positions
#: in whole millimetres, fractions in per cent and one space between columns keep the eleven columns
#: within 80 characters (78 for a camera 10 m away).
CAMERA_COLUMNS = (("camera", "camera", "{}"), ("f\nmm", "focal_length_mm", "{:.1f}"), ("x\nmm", "x_m", "{:.0f}"),
                  ("y\nmm", "y_m", "{:.0f}"), ("z\nmm", "z_m", "{:.0f}"), ("dist\nmm", "distance_m", "{:.0f}"),
                  ("seen\n%", "seen_fraction", "{:.1f}"), ("focus\n%", "in_focus_fraction", "{:.0f}"),
                  ("covered\n%", "covered_after", "{:.1f}"), ("gain\n%", "marginal_gain", "{:.1f}"),
                  ("loss\n%", "loss_if_removed", "{:.1f}"))
#: ``camera_rows`` values in metres and fractions, times this factor in the table.
_TABLE_SCALE = {"x_m": 1e3, "y_m": 1e3, "z_m": 1e3, "distance_m": 1e3, "seen_fraction": 100, "in_focus_fraction": 100,
                "covered_after": 100, "marginal_gain": 100, "loss_if_removed": 100}


def camera_table(rows: list[dict], title: str):
    """The per-camera table of a design (a rich Table), readable in an 80-column terminal.

    Parameters
    ----------
    rows : list of dict
        :func:`scanrig.design.outputs.camera_rows` (metres, fractions).
    title : str
    """
    from rich import box
    from rich.table import Table

    table = Table(title=title, box=box.SIMPLE_HEAD, pad_edge=False, padding=(0, 1, 0, 0))
    for header, _, _ in CAMERA_COLUMNS:
        table.add_column(header, justify="left" if header == "camera" else "right", no_wrap=True)
    for row in rows:
        table.add_row(*(fmt.format(row[key] * _TABLE_SCALE.get(key, 1)) for _, key, fmt in CAMERA_COLUMNS))
    return table


#: Scene objects that only block views: the design does not try to cover them.
OCCLUDER_OBJECTS = ("floor",)


def scene_meshes(name: str):
    """A simulator scene (built-in name or .toml) as the mesh to cover and the occluders.

    Every object except the floor is to be covered; the simulator splits vertices along sharp
    edges for shading, so they are merged back into closed surfaces here.
    """
    import trimesh

    from scanrig.sim.library import load_scene

    objects = load_scene(name).objects
    parts = [o.mesh.copy() for o in objects if o.name not in OCCLUDER_OBJECTS]
    for part in parts:
        part.merge_vertices()
    occluders = [o.mesh for o in objects if o.name in OCCLUDER_OBJECTS]
    return trimesh.util.concatenate(parts), occluders
