"""Every verb's ``--help`` shows an ``Example:`` line, and that example runs as written.

The examples run in one scratch folder, in pipeline order (``VERB_ORDER``), so that an example
finds what the earlier ones made (``scanrig simulate demo_session ...`` first, then calibrate,
detect, reconstruct, ... on ``demo_session``), as a newcomer pasting them would. A verb whose
example cannot run fails with the command line and its output. The demo's example is the test
session's shared quick demo run (``tests/quick_demo.py``), which writes a folder of its own; the
simulator's is the shared small session (``small_session`` in ``tests/conftest.py``, which the
docs pages use too), copied into the scratch folder.
"""

import importlib
import pkgutil
import shlex
import shutil
import subprocess
import sys

import pytest

import scanrig.cli
from scanrig.cli.main import VERB_ORDER, main
from tests.quick_demo import DEMO_TIMEOUT_S, help_example

#: Seconds one example may take (the simulate example renders a whole session).
EXAMPLE_TIMEOUT_S = 1800


def _verbs() -> list[str]:
    found = [m.name for m in pkgutil.iter_modules(scanrig.cli.__path__)
             if hasattr(importlib.import_module(f"scanrig.cli.{m.name}"), "command")]
    rank = {v: i for i, v in enumerate(VERB_ORDER)}
    return sorted(found, key=lambda n: (rank.get(n, len(rank)), n))


VERBS = _verbs()


@pytest.mark.parametrize("verb", VERBS)
def test_help_shows_an_example(verb, capsys):
    assert main([verb, "--help"]) == 0
    out = capsys.readouterr().out
    assert "Example:" in out
    assert help_example(verb).split()[1] == verb


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    return tmp_path_factory.mktemp("examples")


@pytest.mark.slow
@pytest.mark.timeout(DEMO_TIMEOUT_S)   # the demo's waits for the shared quick demo
@pytest.mark.parametrize("verb", VERBS)
def test_example_runs_as_written(verb, workspace, request):
    command = help_example(verb)
    if verb == "demo":
        demo = request.getfixturevalue("quick_demo").example
        assert demo.command == command
        demo.check()
        return
    if verb == "simulate":
        simulated = request.getfixturevalue("small_session")
        assert simulated.command == command
        simulated.check()
        shutil.copytree(simulated.out, workspace / simulated.out.name)
        return
    run = subprocess.run([sys.executable, "-m", "scanrig", *shlex.split(command)[1:]], check=False, cwd=workspace,
                         capture_output=True, text=True, timeout=EXAMPLE_TIMEOUT_S)
    assert run.returncode == 0, (f"the example of `scanrig {verb} --help` does not run as written:\n  {command}\n"
                                 f"exit {run.returncode}\n{run.stderr[-3000:]}")
