"""Fixtures of the reliability tests: one good small session, copied for each case."""

import shutil

import pytest

from tests.reliability.sessions import build_session


@pytest.fixture(scope="module")
def good_session_template(tmp_path_factory):
    return build_session(tmp_path_factory.mktemp("template") / "session")


@pytest.fixture
def good_session(good_session_template, tmp_path):
    """A fresh copy of :func:`tests.reliability.sessions.build_session` for one test."""
    return shutil.copytree(good_session_template, tmp_path / "session")
