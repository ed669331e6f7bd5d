"""Every command block of README.md and docs/*.md runs as written, in order, on simulated sessions.

Each page runs in a folder of its own, its blocks one after the other in one ``bash -e`` each (so
a block sees what the blocks before it wrote). The marks and rules that leave a block or a command
out (docs/contributing.md) are each reported as a skipped test with the page, line and reason.

- ``SESSION``, the placeholder of the real-rig pages, is a small simulated session (3 cameras,
  red spot laser, 4 cube poses, 20 frames) copied into the page's folder. It is the simulator
  page's first session and ``scanrig simulate --help``'s example, the same command line, which
  runs once per test run for all of them (``small_session`` in ``tests/conftest.py``).
- A ``scanrig simulate OUT ...`` or ``scanrig demo --out OUT`` command that opens blocks of
  several pages, identically, runs once; each of those pages gets a copy of the folder it wrote
  (the simulator and the demo are seeded: the copy is what the command writes) and runs the rest
  of its block.
- ``benchmarks/`` is the repository's (a link in the page's folder): a reader runs the benchmarks
  from the clone's root.
- Rules: installing (``python3 -m venv``, ``. .venv/bin/activate``, ``pip install``) is left out
  (the test runs in the installed environment), and so is ``python -m pytest`` (this test is part
  of that run).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.quick_demo import DemoRun, help_example

from .markdown_blocks import PAGES, ROOT, Block, blocks

#: Commands left out by rule: rule name -> pattern of a command (one part of an ``&&`` chain).
RULES = {
    "install": re.compile(r"^python3? -m venv\b|^(\.|source) \S*\.venv/bin/activate\b|^(python3? -m )?pip install\b"),
    "test suite": re.compile(r"^python3? -m pytest\b"),
}
#: The small simulated session that stands in for a real rig's (``SESSION``): the simulator's help
#: example, which is also the first command of docs/simulator.md, so that one run serves all.
SMALL_SESSION = help_example("simulate")
#: Seconds one block may take: a guard against a hang. The README's full demo takes about 4 min on
#: 2 idle cores, and over 10 min beside another test worker at load average 8 to 9.
BLOCK_TIMEOUT_S = 1800


def _rule(command: str) -> str | None:
    return next((name for name, pattern in RULES.items() if pattern.match(command.strip())), None)


def runnable_script(block: Block) -> tuple[str, list[tuple[str, str]]]:
    """The block's script without the commands left out by rule, and those commands with their rule."""
    script = re.sub(r"\\\n\s*", " ", block.commands())   # one line per command
    kept_lines, left_out = [], []
    for line in script.splitlines():
        parts = [part.strip() for part in line.split("&&")]
        kept = []
        for part in parts:
            rule = _rule(part.split("#")[0]) if part.strip() else None
            if rule is None:
                kept.append(part)
            else:
                left_out.append((rule, part.split("#")[0].strip()))
        if kept and any(part.split("#")[0].strip() for part in kept):
            kept_lines.append(" && ".join(kept))
    return "\n".join(kept_lines), left_out


def _plan(page: Path) -> tuple[list[tuple[Block, str]], list[tuple[str, str, str]]]:
    """What to run of ``page``, block by block: (block, its script); and what is skipped:
    (where, reason, command)."""
    to_run, skipped = [], []
    for block in blocks(page):
        if not block.is_command_block:
            continue
        try:
            skip = block.skip()
        except ValueError:
            skip = "unknown mark"   # test_marks_are_known fails on it
        first = next((line.split("  #")[0].strip() for line in block.commands().splitlines()
                      if line.strip() and not line.startswith("#")), "")
        if skip is not None:
            skipped.append((block.where, skip, first))
            continue
        script, left_out = runnable_script(block)
        for rule in dict.fromkeys(rule for rule, _ in left_out):   # one report per rule and block
            skipped.append((block.where, rule, "; ".join(c for r, c in left_out if r == rule)))
        if script:
            to_run.append((block, script))
    return to_run, skipped


def _shared_simulations(plans) -> set[str]:
    """The ``scanrig simulate OUT ...`` and ``scanrig demo --out OUT`` lines that open blocks of
    two or more pages, and :data:`SMALL_SESSION` where it opens a block."""
    pages_of: dict[str, set[Path]] = {}
    for page, (to_run, _) in plans.items():
        for _, script in to_run:
            first = script.partition("\n")[0].strip()
            if (re.match(r"scanrig (simulate [\w.-]+ |demo --out [\w.-]+$)", first)
                    and not re.search(r"[;&|<>$`]", first)):
                pages_of.setdefault(first, set()).add(page)
    return {line for line, pages in pages_of.items() if len(pages) > 1 or line == SMALL_SESSION}


PLANS = {page: _plan(page) for page in PAGES}
RUN_PAGES = [page for page, (to_run, _) in PLANS.items() if to_run]
SKIPPED = [item for _, skipped in PLANS.values() for item in skipped]
SHARED_SIMULATIONS = _shared_simulations(PLANS)


def _environment() -> dict[str, str]:
    env = dict(os.environ, MPLBACKEND="Agg", COLUMNS="80")
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    return env


def _run(script: str, cwd: Path, where: str) -> None:
    result = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", script], check=False, cwd=cwd, env=_environment(),
                            capture_output=True, text=True, timeout=BLOCK_TIMEOUT_S)
    if result.returncode != 0:
        tail = "\n".join((result.stdout + result.stderr).splitlines()[-30:])
        pytest.fail(f"{where}: exit status {result.returncode} running\n{script}\n--- output (last lines) ---\n{tail}",
                    pytrace=False)


class Sessions:
    """The sessions several pages use, made once per test run when a page needs them.

    ``small_session`` returns the shared run of :data:`SMALL_SESSION` (called when first needed).
    """

    def __init__(self, root: Path, small_session: Callable[[], DemoRun]):
        self.root = root
        self._small_session = small_session
        self._simulated: dict[str, Path | None] = {}   # None: the command failed

    def raw(self) -> Path:
        """The small simulated session that stands for ``SESSION``."""
        return self.simulated(SMALL_SESSION, "the small session")

    def simulated(self, command: str, where: str) -> Path:
        """The folder that ``command`` (a line of :data:`SHARED_SIMULATIONS`) writes, run once."""
        if command == SMALL_SESSION:
            run = self._small_session()
            if run.returncode != 0:
                pytest.fail(f"{where}: `{command}` exited {run.returncode}:\n{run.output[-3000:]}", pytrace=False)
            return run.out
        if command not in self._simulated:
            cwd = self.root / f"simulated-{len(self._simulated)}"
            cwd.mkdir()
            self._simulated[command] = None   # a failure is reported by the page that ran it, not rerun
            _run(command, cwd, where)
            self._simulated[command] = cwd / _output_folder(command)
        if self._simulated[command] is None:
            pytest.fail(f"{where}: `{command}` failed on the page that ran it first", pytrace=False)
        return self._simulated[command]


@pytest.fixture(scope="module")
def sessions(tmp_path_factory, request):
    return Sessions(tmp_path_factory.mktemp("docs-sessions"), lambda: request.getfixturevalue("small_session"))


def _output_folder(command: str) -> str:
    """The folder a :data:`SHARED_SIMULATIONS` line writes: ``OUT`` of ``scanrig simulate OUT ...``
    or of ``scanrig demo --out OUT``."""
    words = shlex.split(command)
    return words[words.index("--out") + 1] if words[1] == "demo" else words[2]


def run_page(page: Path, sessions: Sessions, workdir: Path) -> None:
    """Run the command blocks of ``page`` in order in ``workdir`` (see the module docstring)."""
    to_run, _ = PLANS[page] if page in PLANS else _plan(page)
    if any(re.search(r"\bSESSION\b", script) for _, script in to_run):
        shutil.copytree(sessions.raw(), workdir / "SESSION")
    if any(re.search(r"(^|\s)benchmarks/", script) for _, script in to_run):
        (workdir / "benchmarks").symlink_to(ROOT / "benchmarks", target_is_directory=True)
    for block, script in to_run:
        first, _, rest = script.partition("\n")
        if first.strip() in SHARED_SIMULATIONS:
            simulated = sessions.simulated(first.strip(), block.where)
            shutil.copytree(simulated, workdir / simulated.name)
            script = rest
        if script.strip():
            _run(script, workdir, block.where)


@pytest.mark.slow
@pytest.mark.timeout(2 * BLOCK_TIMEOUT_S)
@pytest.mark.parametrize("page", RUN_PAGES, ids=[str(p.relative_to(ROOT)) for p in RUN_PAGES])
def test_command_blocks_run_in_order(page, sessions, tmp_path):
    run_page(page, sessions, tmp_path)


@pytest.mark.parametrize("where, reason, command", SKIPPED, ids=[f"{w} {r}" for w, r, _ in SKIPPED])
def test_skipped_blocks_are_named(where, reason, command):
    """One skipped test per block or command the docs test leaves out, so the summary names them."""
    pytest.skip(f"{where} not run ({reason}): {command}")


def test_every_block_with_commands_says_whether_it_runs():
    """A block showing commands is tagged: bash/sh/console (run here) or text (shown, not run)."""
    untagged = [block.where for page in PAGES for block in blocks(page)
                if not block.lang and re.search(r"^(\$ |scanrig |python3? |pip )", block.text, re.MULTILINE)]
    assert not untagged, f"untagged blocks with commands (tag them bash, or text if they are not to run): {untagged}"


def test_marks_are_known():
    """A mistyped mark would silently run or skip a block: every mark parses."""
    for page in PAGES:
        for block in blocks(page):
            block.skip()   # raises ValueError naming the page and line


def test_a_simulation_that_opens_blocks_of_two_pages_is_shared(tmp_path):
    """Only a ``scanrig simulate`` or ``scanrig demo --out`` line that opens a block on two or more
    pages, word for word, runs once; the folder it writes is the one named after it."""
    texts = {"a.md": "```bash\nscanrig simulate tt --frames 2 --seed 1\nscanrig detect tt\n```\n"
                     "```bash\nscanrig demo --out d\nscanrig report d\n```\n",
             "b.md": "```bash\nscanrig simulate tt --frames 2 --seed 1\n```\n```bash\nscanrig demo --out d\n```\n",
             "c.md": "```bash\nscanrig simulate tt --frames 3 --seed 1\n```\n"
                     "```bash\nscanrig detect tt\nscanrig simulate tt --frames 2 --seed 1\n```\n"}
    for name, text in texts.items():
        (tmp_path / name).write_text(text)
    plans = {tmp_path / name: _plan(tmp_path / name) for name in texts}
    assert _shared_simulations(plans) == {"scanrig simulate tt --frames 2 --seed 1", "scanrig demo --out d"}
    assert [_output_folder(line) for line in sorted(_shared_simulations(plans))] == ["d", "tt"]


def test_the_small_session_opens_a_block():
    """docs/simulator.md opens with the simulator's help example, so that one run of it serves that
    page, the help example's test and ``SESSION``."""
    assert SMALL_SESSION in SHARED_SIMULATIONS
