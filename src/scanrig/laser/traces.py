"""The traces table (``traces.parquet``): one row per candidate detection.

Columns and meaning are the contract in ``docs/architecture.md``. The Parquet file's schema
metadata holds, under the key ``scanrig``, a JSON object with the detection settings and the list
of ``[camera, frame]`` pairs processed (so frames with no candidate are not redone by
``--resume``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa

from scanrig.errors import FileFormatError

SCHEMA = pa.schema([
    ("camera", pa.string()),
    ("frame", pa.string()),
    ("kind", pa.string()),
    ("u", pa.float64()),
    ("v", pa.float64()),
    ("sigma_px", pa.float64()),
    ("peak", pa.float64()),
    ("width_px", pa.float64()),
    ("snr", pa.float64()),
    ("rank", pa.int32()),
    ("cov_uu", pa.float64()),
    ("cov_uv", pa.float64()),
    ("cov_vv", pa.float64()),
    ("line", pa.int32()),
    ("saturated", pa.bool_()),
])
KINDS = ("spot", "stripe")
_META_KEY = b"scanrig"


def make_table(kind: str, columns: dict[str, np.ndarray], camera: str = "", frame: str = "") -> pa.Table:
    """A traces table from per-candidate arrays.

    Parameters
    ----------
    kind : {"spot", "stripe"}
    columns : dict of (n,) arrays
        Every numeric column of :data:`SCHEMA` (``u, v, sigma_px, peak, width_px, snr, rank,
        cov_uu, cov_uv, cov_vv, line, saturated``).
    camera, frame : str
        Filled into every row.

    Returns
    -------
    pyarrow.Table
        With :data:`SCHEMA`.
    """
    n = len(columns["u"])
    text = {"camera": camera, "frame": frame, "kind": kind}
    arrays = [_repeated_string(text[field.name], n) if field.name in text
              else pa.array(np.asarray(columns[field.name]), field.type) for field in SCHEMA]
    return pa.Table.from_arrays(arrays, schema=SCHEMA)


def _repeated_string(value: str, n: int) -> pa.Array:
    """A string array of ``n`` copies of ``value``, built from its buffers (no Python list)."""
    data = value.encode()
    if len(data) * n >= 2**31:  # beyond 32-bit offsets
        return pa.array([value] * n, pa.string())
    offsets = np.arange(n + 1, dtype=np.int32) * np.int32(len(data))
    return pa.StringArray.from_buffers(n, pa.py_buffer(offsets), pa.py_buffer(data * n))


def empty_table() -> pa.Table:
    """A traces table with no rows."""
    return SCHEMA.empty_table()


def write_traces(path: str | Path, table: pa.Table, metadata: dict) -> None:
    """Write ``table`` to ``path`` atomically, with ``metadata`` (JSON-serialisable) in the schema."""
    import pyarrow.parquet as pq

    from scanrig.io.atomic import atomic_write

    table = table.cast(SCHEMA).replace_schema_metadata({_META_KEY: json.dumps(metadata).encode()})
    with atomic_write(path, "wb") as f:
        pq.write_table(table, f)


def read_traces(path: str | Path) -> tuple[pa.Table, dict]:
    """Read and validate a traces file.

    Returns
    -------
    table : pyarrow.Table
        With :data:`SCHEMA` (extra columns are kept after the contract columns).
    metadata : dict
        The ``scanrig`` metadata (empty when the file was written by another tool).

    Raises
    ------
    FileFormatError
        If the file is missing or unreadable, a column is missing or of the wrong type, or
        ``kind`` holds another value than spot/stripe.
    """
    import pyarrow.parquet as pq

    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "traces file not found (run `scanrig detect` first)")
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as exc:
        raise FileFormatError(path, f"not a readable Parquet file: {exc}") from None
    for field in SCHEMA:
        if field.name not in table.column_names:
            raise FileFormatError(path, f"missing column {field.name!r}")
        actual = table.schema.field(field.name).type
        if actual != field.type:
            raise FileFormatError(path, f"column {field.name!r} must be {field.type}, got {actual}")
    kinds = set(table.column("kind").unique().to_pylist())
    if not kinds <= set(KINDS):
        raise FileFormatError(path, f"column 'kind' must hold {KINDS}, got {sorted(kinds - set(KINDS))}")
    raw = (table.schema.metadata or {}).get(_META_KEY)
    try:
        metadata = json.loads(raw) if raw else {}
    except ValueError:  # not JSON, or bytes that are not UTF-8 text
        raise FileFormatError(path, "scanrig metadata is not valid JSON") from None
    if not isinstance(metadata, dict):
        raise FileFormatError(path, f"scanrig metadata must be a JSON object, got {type(metadata).__name__}")
    extra = [c for c in table.column_names if c not in SCHEMA.names]
    return table.select(SCHEMA.names + extra), metadata
