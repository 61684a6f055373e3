"""The issue's targets, on the simulator's corridor and building: places taught from 10 scans
each (the simulator's regions), scored on every other scan against the true labels. The
paper's literal per-scan model is scored alongside on the same logs."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.features.classify import classify
from toolkit.features.evaluate import score
from toolkit.features.fitting import fit
from toolkit.features.model import PAPER, SURROUNDINGS, Config
from toolkit.features.regions import spans_from_frame, training_indices
from toolkit.sim import Simulation, simulate


@pytest.mark.parametrize("scenario", ["corridor", "building"])
def test_surroundings_meet_the_targets(scenario: str, request: pytest.FixtureRequest) -> None:
    """`--none-model surroundings`: the lateral weight its spans choose is 2 (beside the robot)."""
    sim = request.getfixturevalue(f"{scenario}_sim")  # seed 0, shared with other tests
    ours, paper = (score(scenario, config, sim=sim) for config in (SURROUNDINGS, PAPER))
    assert ours.lateral_weight == 2.0
    assert ours.balanced_accuracy >= 0.95 and ours.ece <= 0.05
    assert min(ours.recall.values()) > 0.85  # no place given up for the others
    assert paper.balanced_accuracy < ours.balanced_accuracy - 0.3 and paper.ece > 0.5


def test_default_tells_the_untaught_corridor_as_none(corridor_sim: Simulation) -> None:
    """The corridor scenario teaches four spots (windows, a door, a corner); the plain corridor
    between them, most of the log, is taught as nothing and must come out "none". The
    default's open set learns it from the training log's scans no taught place claims;
    without it (`open_set="never"`) the trees call the plain corridor a door."""
    ours = score("corridor", Config(), sim=corridor_sim)
    closed = score("corridor", Config(open_set="never"), sim=corridor_sim)
    assert ours.recall["none"] >= 0.9
    assert ours.balanced_accuracy >= 0.95 and ours.ece <= 0.05
    assert closed.recall["none"] < 0.2 and closed.ece > 0.5


def test_open_set_stays_off_where_every_place_is_taught() -> None:
    """A random world (seed 3) whose places are all taught, the corridor by one span: the
    claims leave no background (a one-span place keeps the scans the trees give it), so
    the default labels exactly as the closed set does, with no "none"."""
    run = simulate("random", seed=3)
    ds = run.dataset
    spans = spans_from_frame(run.regions, ds.t)
    training = training_indices(spans)
    assert ds.groundtruth is not None
    poses = ds.groundtruth[["x", "y", "theta"]].to_numpy()
    models = [
        fit(ds.ranges, ds.laser, training, config, spans, poses)
        for config in (Config(), Config(open_set="never"))
    ]
    labels = [classify(model, ds.ranges, poses) for model in models]
    assert "no 'none' learnt" in models[0].fit_report["open_set"]
    assert not np.any(labels[0].label == "none")
    assert np.array_equal(labels[0].label, labels[1].label)
