"""Fixtures shared by several test folders."""

import json
import os
from collections.abc import Callable
from pathlib import Path

import pytest
from filelock import FileLock
from hypothesis import settings

from tests.quick_demo import DemoRun, QuickDemo, run_quick_demo, run_simulate_example

# Property tests are seeded like every other test: each draws the same examples on every run (from
# a hash of the test), so whether the suite passes does not depend on the draw.
settings.register_profile("seeded", derandomize=True)
settings.load_profile("seeded")


def _once_per_test_run(tmp_path_factory, name: str, make: Callable[[Path], str]) -> str:
    """The record ``make(folder)`` returns (text), made once per test run in ``folder``.

    Under pytest-xdist every worker has its own session: the first one to get here runs ``make``
    in the folder the workers share, and the others wait on the lock and read its record.
    """
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return make(tmp_path_factory.mktemp(name))
    shared = tmp_path_factory.getbasetemp().parent
    record = shared / f"{name}.json"
    with FileLock(shared / f"{name}.lock"):
        if not record.exists():
            record.write_text(make(shared / name))
        return record.read_text()


@pytest.fixture(scope="session")
def quick_demo(tmp_path_factory) -> QuickDemo:
    """The quick demo's two runs, made once per test run (``tests/quick_demo.py``); read only."""
    return QuickDemo.from_json(_once_per_test_run(tmp_path_factory, "quick-demo",
                                                  lambda folder: run_quick_demo(folder).to_json()))


@pytest.fixture(scope="session")
def small_session(tmp_path_factory) -> DemoRun:
    """``scanrig simulate --help``'s example, run once per test run; its folder is read only (copy
    it to work in it). The simulate example's test and the docs pages' ``SESSION`` use it."""
    record = _once_per_test_run(tmp_path_factory, "small-session",
                                lambda folder: json.dumps(run_simulate_example(folder).to_record()))
    return DemoRun.from_record(json.loads(record))
