"""Every relative link of README.md and docs/*.md, and every repository path they name, exists."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from .markdown_blocks import PAGES, ROOT

_LINK = re.compile(r"\[[^\]]*\]\((?P<target>[^)\s]+)(?:\s+\"[^\"]*\")?\)")
#: A repository path in text or code: tests/…, docs/…, src/…, benchmarks/… (not part of a longer path).
_PATH = re.compile(r"(?<![\w./-])(?P<path>(?:tests|docs|src|benchmarks)/[^\s`'\"(),;:\]|]*)")
#: A page named without a folder (``file-formats.md``, ``PROVENANCE.md``): next to the page, at the top
#: or anywhere under one of the folders above.
_PAGE_NAME = re.compile(r"(?<![\w./(-])(?P<name>[A-Za-z][\w-]*\.md)\b")
_PLACEHOLDER = re.compile(r"[<{]|…|\.\.\.|^[A-Z]+$")   # <camera>, {name}, …, FILE


def anchors(page: Path) -> set[str]:
    """GitHub's anchors of the headings of ``page``: lower case, punctuation dropped, spaces to '-'."""
    text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.MULTILINE | re.DOTALL)
    headings = re.findall(r"^#{1,6}\s+(.*?)\s*#*\s*$", text, flags=re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", h.lower()).replace(" ", "-") for h in headings}


def broken_links(page: Path) -> list[str]:
    """The relative links of ``page`` whose file, or heading anchor in a page, does not exist."""
    broken = []
    for match in _LINK.finditer(page.read_text(encoding="utf-8")):
        target = match["target"]
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):   # http:, https:, mailto:
            continue
        path_part, _, anchor = target.partition("#")
        path = (page.parent / path_part).resolve() if path_part else page
        if not path.exists():
            broken.append(target)
        elif anchor and path.suffix == ".md" and anchor not in anchors(path):
            broken.append(f"{target} (no such heading)")
    return broken


def missing_paths(page: Path) -> list[str]:
    """The repository paths and pages named in ``page`` that do not exist (a glob must match something)."""
    missing = []
    for match in _PATH.finditer(page.read_text(encoding="utf-8")):
        parts = []
        for part in match["path"].rstrip(".").split("/"):
            if _PLACEHOLDER.search(part):
                break
            parts.append(part)
        path = "/".join(parts)
        if not any(ROOT.glob(path) if "*" in path else [ROOT / path] if (ROOT / path).exists() else []):
            missing.append(match["path"])
    for match in _PAGE_NAME.finditer(page.read_text(encoding="utf-8")):
        if not any((folder / match["name"]).is_file() for folder in (page.parent, ROOT)) and not any(
                next((ROOT / top).rglob(match["name"]), None) for top in ("tests", "docs", "src", "benchmarks")):
            missing.append(match["name"])
    return missing


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_relative_links_exist(page):
    assert broken_links(page) == []


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_named_repository_paths_exist(page):
    assert missing_paths(page) == []


def test_a_missing_file_a_missing_heading_and_a_missing_path_are_found(tmp_path, monkeypatch):
    page = tmp_path / "page.md"
    (tmp_path / "other.md").write_text("# Other page\n\n## Its `part`: two\n")
    page.write_text("See [other](other.md#its-part-two), [gone](gone.md), [bad](other.md#nope),\n"
                    "[web](https://example.org/x), `src/scanrig/cli/main.py`, `tests/data/<set>/`,\n"
                    "`benchmarks/bench_*.py`, `src/scanrig/no_such_module.py`, `docs/nothing_*.md`,\n"
                    "other.md, README.md and NOTES.md.\n")
    assert broken_links(page) == ["gone.md", "other.md#nope (no such heading)"]
    assert missing_paths(page) == ["src/scanrig/no_such_module.py", "docs/nothing_*.md", "NOTES.md"]
