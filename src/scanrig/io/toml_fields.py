"""Reading TOML files with errors that name the file and the field."""

from __future__ import annotations

import difflib
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path

from scanrig.errors import FileFormatError


def read_toml(path: str | Path) -> dict:
    """Parse a TOML file, raising :class:`FileFormatError` naming it when absent or malformed."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise FileFormatError(path, "file not found") from None
    except IsADirectoryError:
        raise FileFormatError(path, "is a folder, expected a TOML file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise FileFormatError(path, f"not valid TOML: {exc}") from None


def check_keys(table: Mapping, allowed: Iterable[str], required: Iterable[str], path: Path, where: str) -> None:
    """Raise :class:`FileFormatError` for an unknown key ("did you mean") or a missing required key.

    Parameters
    ----------
    table : mapping
        The parsed TOML table.
    allowed, required : iterable of str
        Keys that may appear, and keys that must.
    path : Path
        The file, for the message.
    where : str
        The table's place in the file, e.g. ``"[[cameras]] #2"``.
    """
    allowed = list(allowed)
    # Unknown keys first: a misspelt key is the likely cause of a "missing" one.
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else f"; allowed: {sorted(allowed)}"
            raise FileFormatError(path, f"{where}: unknown field {key!r}{hint}")
    for key in required:
        if key not in table:
            raise FileFormatError(path, f"{where}: missing field {key!r}")
