"""Fixtures shared by several test folders."""

import pytest

from tests.quick_demo import QuickDemo, run_quick_demo


@pytest.fixture(scope="session")
def quick_demo(tmp_path_factory) -> QuickDemo:
    """The quick demo's two runs, made once per test session (``tests/quick_demo.py``); read only."""
    return run_quick_demo(tmp_path_factory.mktemp("quick-demo"))
