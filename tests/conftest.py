"""Shared fixtures: the committed stomach and simulators (fresh per test)."""

import warnings

import pytest

from mjendo import anatomy

warnings.filterwarnings("ignore", message="flex 'stomach' is not rigid")


@pytest.fixture(scope="session")
def stomach():
    return anatomy.load()
