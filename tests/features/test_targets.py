"""The issue's targets, on the simulator's corridor and building: places taught from 10 scans
each (the simulator's regions), scored on every other scan against the true labels. The
paper's literal per-scan model is scored alongside on the same logs."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.features.classify import classify
from toolkit.features.evaluate import score
from toolkit.features.fitting import fit
from toolkit.features.metrics import balanced_accuracy
from toolkit.features.model import PAPER, SURROUNDINGS, Config
from toolkit.features.regions import Span, spans_from_frame, training_indices
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
    without it (`open_set="never"`) the trees call the plain corridor a door (the labels of
    session 23: session 24's door calls only near an opening beside the laser,
    `beside_reach`, give a share back, ECE 0.43)."""
    ours = score("corridor", Config(), sim=corridor_sim)
    closed = score(
        "corridor", Config(open_set="never", beside_reach=0.0, narrow_opening=0.0), sim=corridor_sim
    )
    assert ours.recall["none"] >= 0.9
    assert ours.balanced_accuracy >= 0.95 and ours.ece <= 0.05
    assert closed.recall["none"] < 0.2 and closed.ece > 0.5


def test_untaught_corridor_is_none_on_another_scenario_seed() -> None:
    """The corridor scenario at seed 1: the door's two spans sit at the doorway's edges,
    and with the claims until session 17 (a tenth of the held-out spans' scans may be missed)
    the door claimed the plain corridor: no "none" was learnt (balanced accuracy 0.770,
    ECE 0.822). A quarter: the plain corridor comes out "none"."""
    ours = score("corridor", Config(), seed=1)
    assert ours.recall["none"] >= 0.9  # 0.978
    assert ours.balanced_accuracy >= 0.95 and ours.ece <= 0.05  # 0.964, 0.011


def test_open_set_stays_off_where_every_place_is_taught() -> None:
    """A random world (seed 3) whose places are all taught, the corridor by one span: the
    claims leave no background (a one-span place keeps the scans the trees give it), so
    the default labels exactly as the closed set does, with no "none"."""
    run, spans, training, poses = _taught_world(3)
    ds = run.dataset
    models = [
        fit(ds.ranges, ds.laser, training, config, spans, poses)
        for config in (Config(), Config(open_set="never"))
    ]
    labels = [classify(model, ds.ranges, poses) for model in models]
    assert "no 'none' learnt" in models[0].fit_report["open_set"]
    assert not np.any(labels[0].label == "none")
    assert np.array_equal(labels[0].label, labels[1].label)


def test_open_set_stays_off_where_a_taught_place_is_most_of_the_log() -> None:
    """A random world (seed 717) whose corridor is 77% of the log, taught by two spans at the
    log's start, where windows and a door are in view ahead. The claims until session 17
    (`claim_shape`: also Mozos et al.'s whole-scan shape, the view to the range limit)
    learnt that view, claimed 0.03 of the corridor and 0.245 of the log, and "none" took
    0.81 of the scans; on what is beside the laser the places claim 0.62 of the log: no
    "none" is learnt and the default labels as the closed set does."""
    run, spans, training, poses = _taught_world(717)
    ds = run.dataset
    truth = np.asarray(run.labels)
    assert np.mean(truth == "corridor") > 0.7 and set(truth) == {s.feature for s in spans}
    configs = (Config(), Config(open_set="never"), Config(claim_shape=True, claim_quantile=0.1))
    models = [fit(ds.ranges, ds.laser, training, config, spans, poses) for config in configs]
    labels = [classify(model, ds.ranges, poses).label for model in models]
    assert "no 'none' learnt" in models[0].fit_report["open_set"]
    assert not np.any(labels[0] == "none")
    assert np.array_equal(labels[0], labels[1])
    assert np.mean(labels[0][truth == "corridor"] == "corridor") > 0.9  # 0.988
    # session 16's claims: "none" learnt, and it takes most of the corridor
    assert "'none' learnt" in models[2].fit_report["open_set"]
    assert np.mean(labels[2][truth == "corridor"] == "none") > 0.5  # corridor found in 0.05


def _taught_world(seed: int) -> tuple[Simulation, list[Span], dict[str, np.ndarray], np.ndarray]:
    """A random world's run, its regions' spans and training scans, and its true poses."""
    run = simulate("random", seed=seed)
    spans = spans_from_frame(run.regions, run.dataset.t)
    assert run.dataset.groundtruth is not None
    return (
        run,
        spans,
        training_indices(spans),
        run.dataset.groundtruth[["x", "y", "theta"]].to_numpy(),
    )


def test_leaf_weight_keeps_an_untaught_door_the_trees_find() -> None:
    """Random world 2011, run a: its untaught door (20 scans, 1.7 m of path) is given to the
    door by the taught-only trees (0.5-0.7), but the self-trained corridor's light scans
    (0.013 each) form leaves of their own where it lies, its margin falls under the HMM's two
    switches and the whole stay is called corridor. A leaf of the self-trained trees that
    must hold half a taught scan's weight (`leaf_weight` 0.5) keeps it (session 21:
    recall 0.0 -> 0.8, balanced accuracy 0.853 -> 0.959)."""
    run, spans, training, poses = _taught_world(2011)
    ds = run.dataset
    truth = np.asarray(run.labels)
    rest = np.ones(ds.n_scans, dtype=bool)
    rest[np.concatenate(list(training.values()))] = False
    door = np.flatnonzero((truth == "door") & rest)
    stays = np.split(door, np.flatnonzero(np.diff(door) > 1) + 1)
    stay = max(stays, key=len)  # the untaught door's whole stay
    assert len(stay) >= 15
    found, ba = [], []
    for weight in (0.0, 0.5):
        model = fit(ds.ranges, ds.laser, training, Config(leaf_weight=weight), spans, poses)
        label = classify(model, ds.ranges, poses).label
        found.append(float(np.mean(label[stay] == "door")))
        ba.append(balanced_accuracy(truth[rest], label[rest]))
    assert found[0] < 0.2 and found[1] >= 0.6
    assert ba[1] > ba[0] + 0.05


def test_evaluate_refuses_a_row_it_does_not_have_in_one_line() -> None:
    """`--rows 99` is a user's typo: a usage line naming the rows there are, no traceback."""
    import subprocess
    import sys

    res = subprocess.run(
        [sys.executable, "-m", "toolkit.features.evaluate", "--seeds", "0", "--rows", "3,99"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2
    assert "Traceback" not in res.stderr
    from toolkit.features.evaluate import ABLATION

    last = res.stderr.strip().splitlines()[-1]
    assert last.endswith(f"--rows: no ablation row 99 (rows 0-{len(ABLATION) - 1})")
