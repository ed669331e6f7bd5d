"""Validation helpers for array arguments at public boundaries.

Each helper returns a float64 array (a copy only when a conversion is needed) or raises
:class:`~scanrig.errors.ShapeError` naming the argument with the expected and actual shape.
"""

from __future__ import annotations

import numpy as np

from scanrig.errors import InputError, ShapeError


def check_points(points, dim: int, name: str) -> np.ndarray:
    """Return ``points`` as a float64 array of shape ``(N, dim)``.

    Parameters
    ----------
    points : array_like of shape (N, dim)
        Rows of coordinates. A single point of shape ``(dim,)`` is not accepted: pass ``[p]``.
    dim : int
        Number of columns expected (2 for pixels, 3 for points).
    name : str
        Argument name used in the error message.

    Raises
    ------
    ShapeError
        If the array is not two-dimensional with ``dim`` columns or is not numeric.
    """
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} must be a numeric array of shape (N, {dim}): {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ShapeError(f"{name} must have shape (N, {dim}), got {arr.shape}")
    return arr


def check_matrix(matrix, shape: tuple[int, ...], name: str) -> np.ndarray:
    """Return ``matrix`` as a finite float64 array of exactly ``shape``.

    Raises
    ------
    ShapeError
        If the shape differs or any entry is NaN or infinite.
    """
    try:
        arr = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} must be a numeric array of shape {shape}: {exc}") from None
    if arr.shape != shape:
        raise ShapeError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ShapeError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def check_positive_int(value, name: str) -> int:
    """Return ``value`` as an ``int`` if it is a positive integer, else raise :class:`InputError`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
        raise InputError(f"{name} must be a positive integer, got {value!r}")
    return int(value)
