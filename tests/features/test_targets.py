"""The issue's targets, on the simulator's corridor and building: places taught from 10 scans
each (the simulator's regions), scored on every other scan against the true labels. The
paper's literal per-scan model is scored alongside on the same logs."""

from __future__ import annotations

import pytest

from toolkit.features.evaluate import LATERAL2, score
from toolkit.features.model import PAPER
from toolkit.sim import simulate


@pytest.mark.parametrize("scenario", ["corridor", "building"])
def test_surroundings_and_lateral_beams_meet_the_targets(scenario: str) -> None:
    sim = simulate(scenario, seed=0)
    ours, paper = (score(scenario, config, sim=sim) for config in (LATERAL2, PAPER))
    assert ours.balanced_accuracy >= 0.95 and ours.ece <= 0.05
    assert min(ours.recall.values()) > 0.85  # no place given up for the others
    assert paper.balanced_accuracy < ours.balanced_accuracy - 0.3 and paper.ece > 0.5
