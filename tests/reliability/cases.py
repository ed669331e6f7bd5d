"""Setup actions shared by the bad-input matrix files: each returns ``setup(session_path)``."""

from __future__ import annotations


def no_change(s):
    return None


def write_text(name: str, text: str):
    """Replace (or create) ``session/name`` with ``text``."""
    return lambda s: (s / name).write_text(text)


def write_bytes(name: str, data: bytes):
    return lambda s: (s / name).write_bytes(data)


def edit_text(name: str, old: str, new: str):
    """Replace the first ``old`` by ``new`` in ``session/name`` (which must contain it)."""
    def setup(s):
        text = (s / name).read_text()
        assert old in text, f"{old!r} not in {name}"
        (s / name).write_text(text.replace(old, new, 1))
    return setup


def remove(name: str):
    return lambda s: (s / name).unlink()


def truncate(name: str, n_bytes: int):
    return lambda s: (s / name).write_bytes((s / name).read_bytes()[:n_bytes])
