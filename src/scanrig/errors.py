"""The project's exception hierarchy.

Every error scanrig raises on purpose derives from :class:`ScanrigError`. Bad input (a wrong
shape, a missing field, an unreadable file) raises a subclass of :class:`InputError`, which is
also a :class:`ValueError`, so callers that only know Python's built-ins still catch it. The CLI
turns an :class:`InputError` into one line and exit status 2.

Messages name the argument, field or file and say what was expected.
"""

from __future__ import annotations

from pathlib import Path


class ScanrigError(Exception):
    """Base class of every error scanrig raises deliberately."""


class InputError(ScanrigError, ValueError):
    """Bad input: an argument, field or file is not what was expected."""


class ShapeError(InputError):
    """An array argument has the wrong shape or dtype."""


class FileFormatError(InputError):
    """A file is missing, unreadable, or does not follow its documented format.

    Parameters
    ----------
    path : str or Path
        The file at fault; it leads the message.
    reason : str
        What is wrong and what was expected.
    """

    def __init__(self, path: str | Path, reason: str):
        self.path = Path(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")

    def __reduce__(self):
        # Rebuild from (path, reason), so the error survives pickling across worker processes.
        return (type(self), (self.path, self.reason))


class EstimationError(ScanrigError, RuntimeError):
    """A whole estimate failed (e.g. a calibration that cannot converge); the message says what to do."""
