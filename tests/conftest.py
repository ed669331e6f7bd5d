"""Fixtures shared by several test folders."""

import os

import pytest
from filelock import FileLock

from tests.quick_demo import QuickDemo, run_quick_demo


@pytest.fixture(scope="session")
def quick_demo(tmp_path_factory) -> QuickDemo:
    """The quick demo's two runs, made once per test run (``tests/quick_demo.py``); read only.

    Under pytest-xdist every worker has its own session: the first one to get here runs the demo
    in the folder the workers share, and the others wait on the lock and read its record.
    """
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return run_quick_demo(tmp_path_factory.mktemp("quick-demo"))
    shared = tmp_path_factory.getbasetemp().parent
    record = shared / "quick-demo.json"
    with FileLock(shared / "quick-demo.lock"):
        if not record.exists():
            record.write_text(run_quick_demo(shared / "quick-demo").to_json())
        return QuickDemo.from_json(record.read_text())
