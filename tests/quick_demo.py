"""The quick demo, run once per test run for every test that reads it (``tests/conftest.py``).

``scanrig demo --quick`` is the slowest thing the tests run (minutes on a shared 2-core machine),
so it runs twice per test run, and never more, however many pytest-xdist workers there are (the
first worker that needs it runs it; the others wait for it and read its record). Both runs start
together, each in a process of its own (the thread counts of OpenMP, OpenBLAS, MKL and torch are
fixed when a process starts):

- ``example``: the demo's ``--help`` example exactly as written
  (``scanrig demo --out demo_run --quick --seed 1``), two threads per library. The demo's tests,
  and the help-example test read it;
- ``one_thread``: the same demo with ``--workers 1`` and one thread per library, which the
  determinism test compares with ``example`` file by file.

Tests only read these folders; one that changes files works on a copy.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

#: Seconds a quick demo run may take (2-4 minutes on 2 idle cores; many more on a shared machine).
DEMO_TIMEOUT_S = 1800
#: Terminal width for the runs: wide enough that no cell of the demo's summary tables wraps.
WIDE_COLUMNS = 1000
#: Environment variables that set a library's thread count.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


def help_example(verb: str) -> str:
    """The ``Example: scanrig ...`` line of ``scanrig VERB --help`` (the verb's docstring).

    Raises
    ------
    AssertionError
        The docstring has no example line.
    """
    doc = importlib.import_module(f"scanrig.cli.{verb}").command.__doc__ or ""
    match = re.search(r"^\s*Example:\s*(scanrig .+?)\s*$", doc, re.MULTILINE)
    assert match, f"scanrig {verb}: the docstring has no 'Example: scanrig ...' line"
    return match.group(1)


@dataclass(frozen=True)
class DemoRun:
    """One finished ``scanrig`` process (the demo, or the simulator's help example).

    Attributes
    ----------
    command : str
        The command line as run (``scanrig ...``).
    out : Path
        The session folder it wrote.
    returncode : int
    output : str
        stdout and stderr together.
    """

    command: str
    out: Path
    returncode: int
    output: str

    def table_rows(self) -> dict[str, list[str]]:
        """The rows of the summary tables the demo printed: first cell -> the other cells."""
        rows = {}
        for line in self.output.splitlines():
            cells = [cell.strip() for cell in line.split("│")[1:-1]]
            if len(cells) >= 2 and cells[0]:
                rows[cells[0]] = cells[1:]
        return rows

    def check(self) -> None:
        """Fail with the command and the end of its output unless it exited 0."""
        assert self.returncode == 0, f"{self.command} exited {self.returncode}:\n{self.output[-3000:]}"

    def to_record(self) -> dict:
        """The run as JSON-ready values, read back by :meth:`from_record`."""
        return dataclasses.asdict(self) | {"out": str(self.out)}

    @classmethod
    def from_record(cls, record: dict) -> DemoRun:
        return cls(**(record | {"out": Path(record["out"])}))


@dataclass(frozen=True)
class QuickDemo:
    """The two runs of the test session (see the module docstring)."""

    example: DemoRun
    one_thread: DemoRun

    def to_json(self) -> str:
        """The record another test process reads back with :meth:`from_json`."""
        return json.dumps({"example": self.example.to_record(), "one_thread": self.one_thread.to_record()})

    @classmethod
    def from_json(cls, text: str) -> QuickDemo:
        return cls(**{name: DemoRun.from_record(run) for name, run in json.loads(text).items()})


def _start(command: str, cwd: Path, threads: int) -> subprocess.Popen:
    env = os.environ | {name: str(threads) for name in THREAD_VARIABLES} | {"COLUMNS": str(WIDE_COLUMNS)}
    cwd.mkdir(parents=True)
    return subprocess.Popen([sys.executable, "-m", "scanrig", *shlex.split(command)[1:]], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def run_quick_demo(folder: Path) -> QuickDemo:
    """Run the demo's help example and its one-thread twin side by side in ``folder``.

    Parameters
    ----------
    folder : Path
        An empty folder; each run writes ``<folder>/<run>/demo_run``.

    Returns
    -------
    QuickDemo
    """
    example = help_example("demo")
    words = shlex.split(example)
    assert "--quick" in words, f"the demo's help example is not a quick run: {example}"
    out_name = words[words.index("--out") + 1]
    commands = {"example": example, "one_thread": f"{example} --workers 1"}
    threads = {"example": 2, "one_thread": 1}
    started = {name: _start(command, folder / name, threads[name]) for name, command in commands.items()}
    runs = {}
    for name, process in started.items():
        output = process.communicate(timeout=DEMO_TIMEOUT_S)[0]
        runs[name] = DemoRun(commands[name], folder / name / out_name, process.returncode, output)
    return QuickDemo(**runs)


def run_simulate_example(folder: Path) -> DemoRun:
    """``scanrig simulate --help``'s example as written, in ``folder`` (created if need be).

    The small session it writes is the one several tests work on (``small_session`` in
    ``tests/conftest.py``): the help example's test and the docs pages' ``SESSION``.
    """
    command = help_example("simulate")
    folder.mkdir(parents=True, exist_ok=True)
    run = subprocess.run([sys.executable, "-m", "scanrig", *shlex.split(command)[1:]], check=False, cwd=folder,
                         capture_output=True, text=True, timeout=DEMO_TIMEOUT_S)
    return DemoRun(command, folder / shlex.split(command)[2], run.returncode, run.stdout + run.stderr)
