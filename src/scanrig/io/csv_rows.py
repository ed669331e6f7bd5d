"""Read a small CSV table whose every row must match its header, with errors naming the file."""

from __future__ import annotations

import csv
from pathlib import Path

from scanrig.errors import FileFormatError


def read_csv_rows(path: Path, required: tuple[str, ...], what: str,
                  columns: tuple[str, ...] | None = None) -> list[tuple[int, dict]]:
    """The data rows of a CSV file, each with its line number.

    Parameters
    ----------
    path : Path
    required : tuple of str
        Columns the header must name (others are allowed).
    what : str
        What the file is, for the message when it is missing (``"corners file"``).
    columns : tuple of str, optional
        The full header, optional columns included, for the message when a column is missing
        (default ``required``).

    Returns
    -------
    list of (int, dict)
        Line number and the row's cells by column name; possibly empty.

    Raises
    ------
    FileFormatError
        Missing file, a missing column, text that is not UTF-8 CSV, or a row with more or fewer
        cells than the header.
    """
    if not path.is_file():
        raise FileFormatError(path, f"{what} not found")
    try:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames or []
            missing = [c for c in required if c not in header]
            if missing:
                raise FileFormatError(path, f"missing column(s) {missing}; expected header {','.join(columns or required)}")
            rows = [(reader.line_num, row) for row in reader]
    except (UnicodeDecodeError, csv.Error) as exc:
        raise FileFormatError(path, f"not a UTF-8 CSV file: {exc}") from None
    ragged = [line for line, row in rows if None in row or None in row.values()]
    if ragged:
        raise FileFormatError(path, f"line {ragged[0]}: the cells do not match the header's {len(header)} columns")
    return rows
