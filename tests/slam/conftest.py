"""Fixtures shared by the mapper's tests."""

from __future__ import annotations

import pytest

import toolkit
from toolkit.sim import simulate


@pytest.fixture(scope="module")
def building() -> toolkit.Dataset:
    """The simulator's building, seed 0: loops, corridors and their revisits, with truth."""
    return simulate("building", seed=0).dataset
