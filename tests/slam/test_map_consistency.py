"""The occupancy grid's truth-free consistency (`render.grid_consistency`): a map whose poses
are wrong scores worse than the truth's, a rigid turn of the same map hardly moves it, and
`toolkit map` writes it to metrics.json from the grid it writes as map.pgm."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import toolkit
from toolkit import mapping, se2
from toolkit.poses import truth_poses
from toolkit.sim import Simulation, simulate
from toolkit.slam import render


def _figure(ds: toolkit.Dataset, robot: np.ndarray) -> dict[str, float | int | None]:
    return render.map_consistency(ds, robot)


def _kinked(poses: np.ndarray, degrees: float) -> np.ndarray:
    """`poses` with the second half turned by `degrees` about the halfway pose."""
    half = len(poses) // 2
    rest = se2.compose(np.broadcast_to(se2.inverse(poses[half]), poses[half:].shape), poses[half:])
    turn = se2.compose(poses[half], np.array([0.0, 0.0, np.radians(degrees)]))
    out = poses.copy()
    out[half:] = se2.compose(np.broadcast_to(turn, rest.shape), rest)
    return out


def test_a_heading_kink_scores_worse_than_the_truth(building_sim: Simulation) -> None:
    ds = building_sim.dataset
    truth = truth_poses(ds)
    assert truth is not None
    right = _figure(ds, truth)
    kinked = _figure(ds, _kinked(truth, 2.0))
    assert (
        right["returns"] == kinked["returns"] == (ds.ranges <= 30.0).sum()
    )  # every return within reach
    # the building's second half revisits the first's rooms: its walls come out doubled
    assert isinstance(right["conflict"], float) and isinstance(kinked["conflict"], float)
    assert kinked["conflict"] > 3 * right["conflict"]
    assert isinstance(right["cells"], float) and isinstance(kinked["cells"], float)
    assert kinked["cells"] > 1.1 * right["cells"]
    # the same map turned by 1 deg (walls no longer along the grid's rows) moves far less
    c = truth[:, :2].mean(axis=0)
    about = se2.compose(np.array([c[0], c[1], np.radians(1.0)]), np.array([-c[0], -c[1], 0.0]))
    turned = _figure(ds, se2.compose(np.broadcast_to(about, truth.shape), truth))
    assert isinstance(turned["conflict"], float)
    assert abs(turned["conflict"] - right["conflict"]) < 0.2 * (
        kinked["conflict"] - right["conflict"]
    )


def test_conflict_counts_returns_without_an_occupied_neighbour() -> None:
    hits = np.zeros((5, 6), np.int32)
    hits[0, 0], hits[2, 3], hits[4, 5] = 2, 3, 5
    img = np.full(hits.shape, 254, np.uint8)  # free, but for:
    img[1, 1] = 0  # occupied, next to (0, 0) diagonally
    img[4, 4] = 0  # occupied, next to (4, 5) on the grid's edge
    img[2, 2] = img[3, 3] = 205  # unknown, next to (2, 3): not an obstacle
    figure = render.grid_consistency(hits, img)
    assert figure == {"conflict": 0.3, "cells": 300.0, "returns": 10}  # (2, 3)'s 3 of 10
    assert render.grid_consistency(np.zeros_like(hits), img)["conflict"] is None


def test_the_grid_is_map_pgms() -> None:
    """map.pgm's three values from the hit ratio: 0 at or above `occupied`, 254 under `free`."""
    hits = np.array([[0, 1, 1, 1, 0]], np.int32)
    seen = np.array([[0, 4, 5, 20, 3]], np.int32)  # ratios -, 0.25, 0.2, 0.05, 0
    img = np.full(hits.shape, 205, np.uint8)
    render._classify(hits, seen, 0.25, 0.1, img)
    assert img.tolist() == [[205, 0, 205, 254, 254]]


def test_metrics_json_carries_the_grids_consistency(tmp_path: Path) -> None:
    ds = simulate("corridor", seed=3, scans=150).dataset
    run = mapping.map_run(ds, tmp_path / "run", loops=False)
    written = json.loads((run.path / "metrics.json").read_text())
    figure = written["consistency"]
    assert figure == _figure(ds, run.result.poses)
    assert figure["returns"] > 0 and 0.0 <= figure["conflict"] < 0.5
    hits, _, _ = render.occupancy(ds, run.result.poses)
    pgm = render.read_pgm(run.path / "map.pgm")[::-1]  # rows as the grid's: y upward
    assert render.grid_consistency(hits, pgm) == figure  # read off map.pgm itself


def test_no_grid_no_figure(tmp_path: Path) -> None:
    """A run without map.png (the report's) traces no grid, so it has no figure."""
    ds = simulate("corridor", seed=3, scans=60).dataset
    run = mapping.map_run(ds, tmp_path / "run", loops=False, outputs=("metrics.json",))
    assert "consistency" not in run.metrics
    assert not (run.path / "map.pgm").exists()
