"""Fixtures shared by the mapper's tests."""

from __future__ import annotations

from pathlib import Path

import pytest

import toolkit
from toolkit.poses import with_drift
from toolkit.sim import simulate


@pytest.fixture(scope="module")
def building() -> toolkit.Dataset:
    """The simulator's building, seed 0: loops, corridors and their revisits, with truth."""
    return simulate("building", seed=0).dataset


def drifted_carmen(real: Path, name: str, seed: int) -> toolkit.Dataset:
    """A real CARMEN corrected log (its corrected poses as the truth), odometry drifted with
    `with_drift(seed)` as the bench drifts it."""
    from importers.carmen import Carmen, CarmenOptions

    path = real / "carmen_radish_corrected" / f"{name}-corrected.log.gz"
    return with_drift(Carmen().read([path], CarmenOptions(poses="groundtruth")), seed=seed)
