"""``target.toml``: the calibration target, read and written with errors naming file and field.

Examples of the file, one per kind (lengths in metres; optional fields in comments)::

    kind = "chessboard"
    inner_corners = [9, 6]        # inner corners along x (columns), y (rows)
    square_m = 0.025
    # margin_m = 0.025            # white border; default one square

    kind = "charuco"
    squares = [7, 5]
    square_m = 0.04
    marker_m = 0.03
    dictionary = "DICT_5X5_1000"  # or an AprilTag family, e.g. "DICT_APRILTAG_36h11"
    # first_marker_id = 0, margin_m = 0.02
    # legacy = true               # printed with OpenCV < 4.6's layout (differs with even rows)
    # flex = true                 # planar kinds only: the board bends, see below

    kind = "circles"              # or "circles_asym" (OpenCV's asymmetric grid)
    grid = [4, 11]
    spacing_m = 0.02
    # diameter_m = 0.01, margin_m = 0.02

    kind = "cube"
    edge_m = 0.2
    squares = 7
    square_m = 0.025
    marker_m = 0.01875
    # dictionary = "DICT_5X5_1000", faces = ["+x", "-x", "+y", "-y", "+z", "-z"]

``flex = true`` (chessboard, charuco, circles, circles_asym; default false) declares a board that
bends (foam, card): the calibration then estimates two parabolic flex terms
(:func:`scanrig.targets.target.flex_shape`). A cube with ``flex = true`` is refused.
"""

from __future__ import annotations

from pathlib import Path

import tomli_w

from scanrig.errors import FileFormatError, InputError
from scanrig.io.atomic import write_text_atomic
from scanrig.io.toml_fields import check_keys, read_toml
from scanrig.targets.target import TARGET_KINDS, Target, charuco, chessboard, circle_grid, cube

#: kind -> (constructor, required fields, optional fields); field names are the constructors' arguments.
_KINDS = {
    "chessboard": (chessboard, ("inner_corners", "square_m"), ("margin_m", "flex")),
    "charuco": (charuco, ("squares", "square_m", "marker_m", "dictionary"),
                ("first_marker_id", "margin_m", "flex", "legacy")),
    "circles": (circle_grid, ("grid", "spacing_m"), ("diameter_m", "margin_m", "flex")),
    "circles_asym": (circle_grid, ("grid", "spacing_m"), ("diameter_m", "margin_m", "flex")),
    "cube": (cube, ("edge_m", "squares", "square_m", "marker_m"), ("dictionary", "faces", "flex")),
}


def load_target(path: str | Path) -> Target:
    """Read a ``target.toml``.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Target

    Raises
    ------
    FileFormatError
        Naming the file and the field: missing file, missing or unknown field, bad value.
    """
    path = Path(path)
    table = read_toml(path)
    return target_from_table(table, path)


def target_from_table(table: dict, path: Path) -> Target:
    """Build a target from a parsed ``target.toml`` table (``path`` only names it in errors)."""
    check_keys(table, ("kind",) + _all_fields(), ("kind",), path, "target")
    kind = table["kind"]
    if not isinstance(kind, str) or kind not in _KINDS:
        raise FileFormatError(path, f"target: kind must be one of {list(TARGET_KINDS)}, got {kind!r}")
    if "legacy" in table and kind != "charuco":
        raise FileFormatError(path, f"target (kind = {kind!r}): legacy applies only to kind = 'charuco' "
                                    "(a ChArUco board printed with OpenCV < 4.6's layout)")
    build, required, optional = _KINDS[kind]
    fields = {k: v for k, v in table.items() if k != "kind"}
    check_keys(fields, required + optional, required, path, f"target (kind = {kind!r})")
    if kind in ("circles", "circles_asym"):
        fields["asymmetric"] = kind == "circles_asym"
    for key in ("inner_corners", "squares", "grid"):
        if isinstance(fields.get(key), list):
            fields[key] = tuple(fields[key])
    try:
        return build(**fields)
    except InputError as exc:
        raise FileFormatError(path, f"target: {exc}") from None


def target_to_toml(target: Target) -> str:
    """The text of a ``target.toml`` describing ``target``."""
    header = "# scanrig calibration target; lengths in metres (see docs/calibration.md)\n"
    return header + tomli_w.dumps(target.spec)


def save_target(target: Target, path: str | Path) -> None:
    """Write ``target.toml`` atomically."""
    write_text_atomic(path, target_to_toml(target))


def _all_fields() -> tuple[str, ...]:
    names = []
    for _, required, optional in _KINDS.values():
        names += [n for n in required + optional if n not in names]
    return tuple(names)
