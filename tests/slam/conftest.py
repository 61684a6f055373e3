"""Fixtures shared by the mapper's tests."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import pytest

import toolkit
from toolkit.poses import with_drift
from toolkit.sim import simulate
from toolkit.slam.grid import LikelihoodGrid
from toolkit.slam.loops import LoopCloser, candidates, path_length
from toolkit.slam.pipeline import keyframes_of


@pytest.fixture(scope="module")
def building() -> toolkit.Dataset:
    """The simulator's building, seed 0: loops, corridors and their revisits, with truth."""
    return simulate("building", seed=0).dataset


def drifted_carmen(
    real: Path, name: str, seed: int, equal_poses: Literal["robot", "laser"] = "laser"
) -> toolkit.Dataset:
    """A real CARMEN corrected log (its corrected poses as the truth), odometry drifted with
    `with_drift(seed)` as the bench drifts it. `equal_poses`: the importer's option (belgioioso,
    freiburg-101 and freiburg-campus: "laser", the default since session 34, reads their poses
    as the laser's and the truth as the robot's behind them; "robot" the reading before it)."""
    from importers.carmen import Carmen, CarmenOptions

    path = real / "carmen_radish_corrected" / f"{name}-corrected.log.gz"
    options = CarmenOptions(poses="groundtruth", equal_poses=equal_poses)
    return with_drift(Carmen().read([path], options), seed=seed)


def reference_grids(
    closer: LoopCloser, a: int, poses: np.ndarray, along: np.ndarray, keys: np.ndarray
) -> tuple[np.ndarray, LikelihoodGrid, LikelihoodGrid]:
    """Scan `a`'s local map (the returns of `LoopCloser.reference_keys`) and the loop
    closer's coarse and fine grids of all of it (the closer cuts the fine one to the box)."""
    cfg = closer.config
    ref = closer.local_points(a, closer.reference_keys(a, along, keys), poses)
    coarse = LikelihoodGrid.build(ref, cfg.coarse, cfg.coarse_sigma, margin=1.0)
    return ref, coarse, LikelihoodGrid.build(ref, cfg.fine, cfg.fine_sigma, margin=0.5)


def loop_candidates(
    ds: toolkit.Dataset, poses: np.ndarray
) -> tuple[LoopCloser, np.ndarray, np.ndarray, list[tuple[int, int, float]]]:
    """The loop closer of `ds` with its default config, the keyframes of `poses` as the mapper
    takes them, their path length, and the loop candidates (a, b, window) among them."""
    closer = LoopCloser(ds.ranges, ds.laser)
    keys = keyframes_of(poses, 0.5, 0.3)
    along = path_length(poses)
    return closer, keys, along, candidates(keys, poses, along, closer.config)
