"""The fenced code blocks of the user documentation, and the marks that tell the docs test what to do.

A block is marked by an HTML comment on the nearest non-blank line above its opening fence (it
does not show on a rendered page)::

    <!-- docs-test: skip real-hardware -->      needs cameras, a pan-tilt head or a printer
    <!-- docs-test: skip slow -->               runs for minutes; covered by its own test

Every block tagged ``bash``, ``sh``, ``shell`` or ``console`` (only its ``$ `` lines) is a command
block; a block that shows commands without running them (a synopsis with ``[--option]``, a
transcript with errors) is tagged ``text``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: The pages a user reads: the README and every page of docs/.
PAGES = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")))
SHELL_LANGUAGES = ("bash", "sh", "shell", "console")
#: Reasons a block may be skipped for (a typo in a mark fails the test rather than skipping).
SKIP_REASONS = ("real-hardware", "slow")

_FENCE = re.compile(r"^(?P<indent>\s*)(?P<fence>`{3,}|~{3,})\s*(?P<lang>[\w+-]*)")
_MARK = re.compile(r"^\s*<!--\s*docs-test:\s*(?P<mark>.*?)\s*-->\s*$")
_SKIP = re.compile(r"^skip (?P<reason>[\w-]+)$")


@dataclass(frozen=True)
class Block:
    """One fenced code block of a page."""

    page: Path
    line: int           # 1-based line of the opening fence
    lang: str           # the info string's first word ('' when untagged)
    text: str           # the body, its fence's indentation removed
    mark: str | None    # the docs-test mark above it, e.g. 'skip real-hardware'

    @property
    def where(self) -> str:
        page = self.page.relative_to(ROOT) if self.page.is_relative_to(ROOT) else self.page
        return f"{page}:{self.line}"

    @property
    def is_command_block(self) -> bool:
        return self.lang in SHELL_LANGUAGES

    def skip(self) -> str | None:
        """The reason if the block is marked to be skipped, else None.

        Raises
        ------
        ValueError
            The mark is not one the docs test knows.
        """
        if self.mark is None:
            return None
        match = _SKIP.match(self.mark)
        if match is None or match["reason"] not in SKIP_REASONS:
            raise ValueError(f"{self.where}: unknown mark <!-- docs-test: {self.mark} -->; marks are "
                             f"'skip REASON' with REASON one of {SKIP_REASONS}")
        return match["reason"]

    def commands(self) -> str:
        """The shell script of the block: a ``console`` block's ``$ `` lines, any other block whole."""
        if self.lang != "console":
            return self.text
        return "\n".join(line[2:] for line in self.text.splitlines() if line.startswith("$ "))


def blocks(page: Path) -> list[Block]:
    """Every fenced code block of ``page``, in order."""
    lines = page.read_text(encoding="utf-8").splitlines()
    found, i = [], 0
    while i < len(lines):
        opening = _FENCE.match(lines[i])
        if opening is None:
            i += 1
            continue
        indent, fence = opening["indent"], opening["fence"]
        end = i + 1
        while end < len(lines) and not lines[end].strip().startswith(fence):
            end += 1
        body = [line[len(indent):] if line.startswith(indent) else line.lstrip() for line in lines[i + 1:end]]
        above = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
        mark = _MARK.match(above)
        found.append(Block(page, i + 1, opening["lang"], "\n".join(body), mark["mark"] if mark else None))
        i = end + 1
    return found
