"""The issue's targets, on the simulator's corridor and building: places taught from 10 scans
each (the simulator's regions), scored on every other scan against the true labels. The
paper's literal per-scan model is scored alongside on the same logs."""

from __future__ import annotations

import pytest

from toolkit.features.evaluate import score
from toolkit.features.model import PAPER, SURROUNDINGS


@pytest.mark.parametrize("scenario", ["corridor", "building"])
def test_surroundings_meet_the_targets(scenario: str, request: pytest.FixtureRequest) -> None:
    """`--none-model surroundings`: the lateral weight its spans choose is 2 (beside the robot)."""
    sim = request.getfixturevalue(f"{scenario}_sim")  # seed 0, shared with other tests
    ours, paper = (score(scenario, config, sim=sim) for config in (SURROUNDINGS, PAPER))
    assert ours.lateral_weight == 2.0
    assert ours.balanced_accuracy >= 0.95 and ours.ece <= 0.05
    assert min(ours.recall.values()) > 0.85  # no place given up for the others
    assert paper.balanced_accuracy < ours.balanced_accuracy - 0.3 and paper.ece > 0.5
