"""``inspection.ply`` and ``inspection.json``: the deviation of every point, and the summary.

Both are written atomically. A file of that name that ``scanrig inspect`` did not write (its PLY
header or JSON lacks the :data:`WRITTEN_BY` mark) is never replaced: :func:`check_outputs_free`
refuses before anything is computed or written.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from scanrig.errors import InputError
from scanrig.inspect.inspection import Inspection
from scanrig.io.atomic import write_text_atomic
from scanrig.io.ply import write_ply

#: The mark every output carries (PLY comment, JSON field, HTML note), so a re-run may replace them.
WRITTEN_BY = "scanrig inspect"
PLY_NAME, JSON_NAME, HTML_NAME = "inspection.ply", "inspection.json", "inspection.html"
OUTPUT_NAMES = (PLY_NAME, JSON_NAME, HTML_NAME)
#: The colour map reaches its ends at this many tolerances (within tolerance: the paler inner half).
COLOUR_SPAN_TOLERANCES = 2.0
#: Diverging matplotlib colour map: blue inside the material (dents), red outside (bumps).
COLOUR_MAP = "RdBu_r"
#: Bytes read from an existing file to find the mark.
MARK_BYTES = 16384


def deviation_rgb(deviation_m: np.ndarray, tolerance_m: float) -> np.ndarray:
    """``(N, 3)`` uint8 colours of a diverging map symmetric about 0, ends at ±2 tolerances."""
    import matplotlib

    x = 0.5 + 0.5 * np.clip(deviation_m / (COLOUR_SPAN_TOLERANCES * tolerance_m), -1.0, 1.0)
    return (matplotlib.colormaps[COLOUR_MAP](x)[:, :3] * 255).round().astype(np.uint8)


def check_outputs_free(out_dir: str | Path, names=OUTPUT_NAMES) -> None:
    """Refuse to go on if ``out_dir`` holds one of ``names`` that scanrig inspect did not write.

    Raises
    ------
    InputError
        ``out_dir`` is a file, or one of the outputs exists without the :data:`WRITTEN_BY` mark.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: --out is an existing file, not a folder")
    for name in names:
        path = out_dir / name
        if path.exists() and not _written_by_inspect(path):
            raise InputError(f"{path}: exists and was not written by {WRITTEN_BY}; "
                             "give another --out folder (nothing was written)")


def _written_by_inspect(path: Path) -> bool:
    if not path.is_file():
        return False
    with open(path, "rb") as f:
        head = f.read(MARK_BYTES)
    return WRITTEN_BY.encode() in head


def summary(inspection: Inspection, *, title: str) -> dict:
    """The content of ``inspection.json`` (SI units)."""
    return {"written_by": WRITTEN_BY, "title": title, "units": "m",
            "cad_from_cloud": inspection.cad_from_cloud.tolist(),
            **inspection.stats.as_dict(),
            "signed": inspection.signed,
            "alignment": inspection.alignment.as_dict(),
            "regions": [r.as_dict() for r in inspection.regions],
            "warnings": list(inspection.warnings), "seed": inspection.seed}


def write_inspection(inspection: Inspection, out_dir: Path, *, points_m: np.ndarray, title: str) -> None:
    """Write ``inspection.ply`` and ``inspection.json`` into ``out_dir`` (created if missing).

    The HTML page is drawn by the report layer (:func:`scanrig.report.inspection_page.write_inspection_page`),
    which may import this package; this package may not import it.

    Parameters
    ----------
    inspection : Inspection
        From :func:`scanrig.inspect.inspect_cloud`.
    out_dir : Path
        Output folder.
    points_m : (N, 3) float array
        The cloud given to ``inspect_cloud`` (cloud frame, metres, same order).
    title : str
        One line naming the inspection (recorded in both files).

    Raises
    ------
    InputError
        ``points_m`` does not match the inspection, or an output exists that this command did not
        write (nothing is written then).
    """
    out_dir = Path(out_dir)
    points_m = np.asarray(points_m, np.float64)
    if points_m.shape != (len(inspection.deviation_m), 3):
        raise InputError(f"points_m must have shape ({len(inspection.deviation_m)}, 3) like the inspection, "
                         f"got {points_m.shape}")
    check_outputs_free(out_dir, (PLY_NAME, JSON_NAME))
    out_dir.mkdir(parents=True, exist_ok=True)
    p = inspection.points_cad(points_m)
    rgb = deviation_rgb(inspection.deviation_m, inspection.stats.tolerance_m)
    comments = [f"written by {WRITTEN_BY}: {' '.join(title.split())}", "units m", "frame CAD",
                ("deviation_m " + ("signed, positive outside the material" if inspection.signed
                                   else "unsigned (open CAD mesh)")),
                (f"colour {COLOUR_MAP} from -{COLOUR_SPAN_TOLERANCES:g} to +{COLOUR_SPAN_TOLERANCES:g} tolerances "
                 f"(tolerance {inspection.stats.tolerance_m:g} m)"), f"seed {inspection.seed}"]
    write_ply(out_dir / PLY_NAME, {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2],
                                   "deviation_m": inspection.deviation_m.astype(np.float32),
                                   "red": rgb[:, 0], "green": rgb[:, 1], "blue": rgb[:, 2]}, comments=comments)
    write_text_atomic(out_dir / JSON_NAME, json.dumps(summary(inspection, title=title), indent=2) + "\n")
