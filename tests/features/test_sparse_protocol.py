"""The random-world protocol with scans far apart (`evaluate --spacing`): each run thinned to
scans about 1 m of path apart, as the Intel log's, so that the sparse-scan rule fires on the
taught and the scored logs; ten taught scans per place among the kept ones."""

from __future__ import annotations

import numpy as np

from toolkit.features import Config
from toolkit.features.descriptors import path_length
from toolkit.features.evaluate import protocol, protocol_scores, teaches_two, thinned, worlds
from toolkit.features.fitting import _sparse
from toolkit.features.regions import spans_from_frame, training_indices
from toolkit.sim import simulate


def test_thinned_runs_are_sparse_and_teach_ten_scans_per_place() -> None:
    """Seed 3 thinned to 1 m: every kept scan at least 1 m of path after the one before (about
    a tenth of the scans), the sparse-scan rule fires on each run, and run a's regions teach
    the corridor and the hall (its door and corners are under 10 m: not taught)."""
    dense = simulate("random", seed=3)
    sim = thinned(dense, 1.0)
    kept = np.searchsorted(dense.dataset.t, sim.dataset.t)
    step = np.diff(dense.distance()[kept])  # along the dense path (a corner's chord is shorter)
    assert step.min() >= 1.0 and np.median(step) < 1.1
    assert 0.05 < sim.dataset.n_scans / dense.dataset.n_scans < 0.12
    assert len(sim.labels) == sim.dataset.n_scans == len(sim.dataset.groundtruth)  # type: ignore[arg-type]
    assert dense.dataset.groundtruth is not None
    poses = dense.dataset.groundtruth[["x", "y", "theta"]].to_numpy()
    assert not _sparse(dense.dataset.n_scans, poses, Config())
    runs = worlds(3, 1.0)
    for run in runs.values():
        poses = run.dataset.groundtruth[["x", "y", "theta"]].to_numpy()
        assert _sparse(run.dataset.n_scans, poses, Config())
    spans = spans_from_frame(runs["a"].regions, runs["a"].dataset.t)
    taught = training_indices(spans)
    assert sorted(taught) == ["corridor", "hall"] and all(len(i) == 10 for i in taught.values())
    assert teaches_two(runs)
    assert {"door", "corner"} <= set(runs["a"].labels)
    # a world whose thinned run a has one place of 10 m or more is left out (seed 0: the
    # corridor alone)
    assert not teaches_two({"a": thinned(simulate("random", seed=0), 1.0)})
    assert path_length(3, None).tolist() == [0.0, 0.1, 0.2]  # (the rule's unit without poses)


def test_only_the_taught_places_are_scored_on_thinned_runs() -> None:
    """Scored with `taught_only`, the untaught door, corners and window of seed 3 are left
    out (as the Intel check scores only its corridor and rooms): the classes scored are the
    taught ones, and the corridor and the hall are told apart in every run (measured
    balanced accuracy 1.00 / 0.99 / 0.90); scored as the dense protocol does, the untaught
    places' scans count as errors."""
    runs = worlds(3, 1.0)
    only = protocol_scores(Config(), runs, taught_only=True)
    every = protocol_scores(Config(), runs)
    for key in "abc":
        assert set(only[key]["recall"]) <= {"corridor", "hall"}
        assert only[key]["ba"] > 0.85
        assert every[key]["ba"] < only[key]["ba"] - 0.2
    table, places = protocol([("default", Config())], (0, 3), spacing=1.0)
    assert table.loc[0, "seeds"] == 1  # seed 0 teaches one place: left out
    assert table.loc[0, "(c) BA mean"] == round(only["c"]["ba"], 3)
    assert set(places["place"]) == {"corridor", "hall"}
