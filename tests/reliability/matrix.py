"""Harness of the bad-input matrix: run a verb in-process and check how it fails."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

from scanrig.cli.main import main


def snapshot(root: Path) -> dict[str, str]:
    """SHA-256 of every file below ``root`` (relative path -> digest)."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def assert_fails_cleanly(argv: list[str], message: str, root: Path, capsys, status: int = 2) -> None:
    """The verb exits with ``status``, prints one ``error:`` line matching ``message``, no
    traceback, and leaves every file that existed below ``root`` unchanged."""
    before = snapshot(root)
    code = main(argv)
    err = capsys.readouterr().err
    assert code == status, f"exit {code}, stderr: {err}"
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, err
    assert re.search(message, lines[0]), f"{lines[0]!r} does not match {message!r}"
    after = snapshot(root)
    assert {k: v for k, v in after.items() if k in before} == before, "an earlier output changed"
