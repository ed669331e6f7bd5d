"""The CAD model: read STL, PLY or OBJ with trimesh, in metres, and check its units against the scan.

CAD exports are usually in millimetres while scanrig works in metres; a model whose size is about
1000 times the cloud's (or 1/1000) is almost surely read in the wrong unit, and is refused with a
message that says which ``--cad-units`` to give.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from scanrig.errors import FileFormatError, InputError

#: Units the CAD file may be written in, and their size in metres.
CAD_UNITS_M = {"m": 1.0, "mm": 1e-3}
#: Suffixes trimesh reads as meshes here.
CAD_SUFFIXES = (".stl", ".ply", ".obj")
#: A CAD larger (or smaller) than the cloud by more than this factor is in the wrong unit: a partial
#: scan covers at least a few percent of its part, and a mm/m mix-up is a factor of 1000.
UNIT_RATIO_LIMIT = 100.0
#: Percentiles of each coordinate that bound the cloud for the unit check (outliers ignored).
EXTENT_PERCENTILES = (1.0, 99.0)


def load_cad(path: str | Path, units: str = "m") -> trimesh.Trimesh:
    """Read a triangle mesh and scale it to metres.

    Parameters
    ----------
    path : str or Path
        STL, PLY or OBJ file holding triangles (a multi-body file is merged into one mesh).
    units : {"m", "mm"}
        Unit of the file's coordinates.

    Returns
    -------
    trimesh.Trimesh
        The mesh, vertices in metres (CAD frame).

    Raises
    ------
    InputError
        ``units`` is not one of :data:`CAD_UNITS_M`.
    FileFormatError
        Missing or unreadable file, another suffix, or a file without triangles (e.g. a PLY of
        points).
    """
    path = Path(path)
    if units not in CAD_UNITS_M:
        raise InputError(f"--cad-units must be one of {', '.join(CAD_UNITS_M)}, got {units!r}")
    if path.suffix.lower() not in CAD_SUFFIXES:
        raise FileFormatError(path, f"expected a CAD mesh ({', '.join(CAD_SUFFIXES)}), got suffix {path.suffix!r}")
    if not path.is_file():
        raise FileFormatError(path, "no such file")
    try:
        loaded = trimesh.load(path, process=True)
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types for malformed files
        raise FileFormatError(path, f"not a readable mesh ({type(exc).__name__}: {exc})") from None
    if isinstance(loaded, trimesh.Scene):                 # several bodies: one mesh in the scene's frame
        bodies = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
        loaded = trimesh.util.concatenate(bodies) if bodies else loaded
    if isinstance(loaded, trimesh.PointCloud) or (isinstance(loaded, trimesh.Trimesh) and len(loaded.vertices)
                                                   and not len(loaded.faces)):
        raise FileFormatError(path, "holds no triangles (a CAD model must be a triangle mesh, not points)")
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise FileFormatError(path, "not a readable mesh (no triangles found)")
    mesh = loaded
    if not np.all(np.isfinite(mesh.vertices)) or mesh.area <= 0:
        raise FileFormatError(path, "the mesh has non-finite vertices or zero area")
    mesh.apply_scale(CAD_UNITS_M[units])
    return mesh


def cloud_extent_m(points_m: np.ndarray) -> float:
    """Diagonal of the box between the 1st and 99th percentiles of each coordinate, metres."""
    lo, hi = np.percentile(points_m, EXTENT_PERCENTILES, axis=0)
    return float(np.linalg.norm(hi - lo))


def check_cad_scale(cad: trimesh.Trimesh, points_m: np.ndarray, cad_label: str = "cad") -> None:
    """Refuse a CAD whose size is ~1000x (or ~1/1000) the cloud's: a millimetre/metre mix-up.

    Parameters
    ----------
    cad : trimesh.Trimesh
        The model, metres.
    points_m : (N, 3) float array
        The scan, metres.
    cad_label : str
        Names the CAD in the message (its file, or ``cad``).

    Raises
    ------
    InputError
        If the ratio of the CAD's bounding-box diagonal to the cloud's exceeds
        :data:`UNIT_RATIO_LIMIT` either way; the message says which unit to give.
    """
    cad_m = float(np.linalg.norm(cad.extents))
    cloud_m = cloud_extent_m(points_m)
    if cloud_m == 0:
        return                                    # a single point has no size to compare
    ratio = cad_m / cloud_m
    if ratio > UNIT_RATIO_LIMIT:
        raise InputError(f"{cad_label}: the CAD is {ratio:.0f}x the size of the cloud ({cad_m:.4g} m vs "
                         f"{cloud_m:.4g} m across): it looks like millimetres read as metres; "
                         f"give --cad-units mm")
    if ratio < 1 / UNIT_RATIO_LIMIT:
        raise InputError(f"{cad_label}: the CAD is 1/{1 / ratio:.0f} of the size of the cloud ({cad_m:.4g} m vs "
                         f"{cloud_m:.4g} m across): it looks like metres read as millimetres; "
                         f"give --cad-units m")
