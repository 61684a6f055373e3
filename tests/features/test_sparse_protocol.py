"""The random-world protocol with scans far apart (`evaluate --spacing`): each run thinned to
scans about 1 m of path apart, as the Intel log's, so that the sparse-scan rule fires on the
taught and the scored logs; ten taught scans per place among the kept ones."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from toolkit.errors import ToolkitError
from toolkit.features import Config, classify
from toolkit.features.classify import (
    class_scores,
    evidence_weights,
    junction_turns,
    near_enclosed,
    path_steps,
    pool_turns,
    switch_probability,
    turn_groups,
    turn_reach,
    turns,
)
from toolkit.features.descriptors import path_length
from toolkit.features.evaluate import protocol, protocol_scores, teaches_two, thinned, worlds
from toolkit.features.fitting import _sparse, fit
from toolkit.features.likelihood import CHUNK, softmax
from toolkit.features.model import FeatureModel
from toolkit.features.regions import spans_from_frame, training_indices
from toolkit.sim import Simulation, simulate
from toolkit.sim.truth import runs as label_runs

#: session 28's default, without the view ahead on a sparse log (`sparse_view_ahead`, session
#: 29): the tests below measured the rules of sessions 23-28 on it. With the view ahead their
#: worlds' figures move (seed 3 thinned, run c: BA 0.85 -> 0.70, its hall lost in the transfer
#: world; the thinned protocol -0.040 +- 0.065 over 20 worlds; the crossings' long turns of
#: seed 3 found without the junction rule), measured in docs/journal/places.md, axis29
BASE28 = Config(sparse_view_ahead=False)


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
    balanced accuracy 1.00 / 0.99 / 0.85); scored as the dense protocol does, the untaught
    places' scans count as errors."""
    runs = worlds(3, 1.0)
    only = protocol_scores(BASE28, runs, taught_only=True)
    every = protocol_scores(BASE28, runs)
    for key in "abc":
        assert set(only[key]["recall"]) <= {"corridor", "hall"}
        assert only[key]["ba"] > 0.8
        assert every[key]["ba"] < only[key]["ba"] - 0.2
    table, places = protocol([("default", BASE28)], (0, 3), spacing=1.0)
    assert table.loc[0, "seeds"] == 1  # seed 0 teaches one place: left out
    assert table.loc[0, "(c) BA mean"] == round(only["c"]["ba"], 3)
    assert set(places["place"]) == {"corridor", "hall"}
    for key in "abc":  # the lowest place's precision per protocol: the 0.8 target
        lowest = places.loc[places["run"] == key, "precision"].min()
        assert table.loc[0, f"({key}) min precision"] == lowest


def test_the_sparse_dwell_calibrates_the_labels_of_a_sparse_log() -> None:
    """On a sparse log the HMM's dwell has `sparse_dwell_stages` (2) stages: at 1 m a scan the
    geometric dwell of 1 m switched place at 0.63 of the scans, leaking a share to every other
    place at each, and the labels were underconfident. Seed 110 thinned to 1 m: ECE in run b
    0.156 -> 0.080 (measured) at the same balanced accuracy (1.00 / 0.97 / 1.00); the fit
    report says so."""
    runs = worlds(110, 1.0)
    now = protocol_scores(BASE28, runs, taught_only=True)
    before = protocol_scores(
        Config(sparse_dwell_stages=0, sparse_view_ahead=False), runs, taught_only=True
    )
    assert now["b"]["ece"] < before["b"]["ece"] - 0.04
    assert now["b"]["ba"] >= before["b"]["ba"] and now["c"]["ba"] >= before["c"]["ba"]
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    poses = a.dataset.groundtruth[["x", "y", "theta"]].to_numpy()
    model = fit(a.dataset.ranges, a.dataset.laser, training_indices(spans), Config(), spans, poses)
    assert model.config.dwell_stages == 2 and "dwell of 2 stages" in model.fit_report["context"]
    # the same run dense keeps `dwell_stages`
    sim = simulate("random", seed=110)
    spans = spans_from_frame(sim.regions, sim.dataset.t)
    assert sim.dataset.groundtruth is not None
    poses = sim.dataset.groundtruth[["x", "y", "theta"]].to_numpy()
    ds = sim.dataset
    dense = fit(ds.ranges, ds.laser, training_indices(spans), Config(), spans, poses)
    assert dense.config.dwell_stages == 1 and "context" not in dense.fit_report


def test_turns_kept_and_worlds_taught_as_the_intel_log() -> None:
    """`--turn 0.5 --entered` (session 25): a scan at every 0.5 rad of a turn on the spot as
    well as every 1 m, as the Intel log's; the runs labelled corridor / room (the doorways,
    windows and crossings are corridor, as the Intel check's ring), the corridor taught from
    two spans of ten scans driven straight (seed 0: both in its one run with ten such), the
    rooms from ten scans in each of two rooms. Without a turn pooled (session 26's default,
    `sparse_turn_pool` None) they reproduce the Intel corridor's failure: the corridor scans
    taken turning on the spot go to room (seed 0, measured: the corridor's turning scans found
    in 0.11 / 0.17 / 0.00 of runs a / b / c, its driving ones 0.77 / 0.84 / 0.11; the rooms
    1.00)."""
    dense = simulate("random", seed=0, entered=True)
    plain, turns = thinned(dense, 1.0), thinned(dense, 1.0, turn=0.5)
    assert turns.dataset.n_scans > plain.dataset.n_scans + 30  # the turns kept (141, 98)
    kept = np.searchsorted(dense.dataset.t, turns.dataset.t)
    assert dense.dataset.groundtruth is not None
    theta = np.unwrap(dense.dataset.groundtruth.theta.to_numpy())
    turned = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(theta)))])[kept]
    along = dense.distance()[kept]
    # each kept scan: the first one 1 m of path or 0.5 rad of turning after the one before
    assert np.all((np.diff(along) >= 1.0) | (np.diff(turned) >= 0.5))
    assert np.mean(np.diff(turned) >= 0.5) > 0.25  # a quarter of them on turns
    runs = worlds(0, 1.0, 0.5, entered=True)
    for run in runs.values():
        assert set(run.labels) <= {"corridor", "room", "hall"}
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    taught = training_indices(spans)
    assert sorted(taught) == ["corridor", "room"] and all(len(i) == 20 for i in taught.values())
    assert list(a.regions.feature) == ["corridor", "corridor", "room", "room"]
    # the corridor's spans driven straight, apart (seed 0: both in its first run, the only
    # one with ten scans driven straight); the rooms' in two rooms
    xy = a.dataset.groundtruth[["x", "y"]].to_numpy()
    corridor = np.sort(taught["corridor"])
    assert np.all(np.hypot(*np.diff(xy[corridor[:10]], axis=0).T) > 0.9)
    assert corridor[10] - corridor[9] >= 10
    room = np.sort(taught["room"])
    assert np.any(a.labels[room[9] : room[10]] != "room")
    scores = protocol_scores(Config(), runs, taught_only=True)
    model_labels = {k: set(v["recall"]) for k, v in scores.items()}
    assert all(labels == {"corridor", "room"} for labels in model_labels.values())
    # the failure: the corridor turning on the spot goes to room, the rooms are found
    train = runs["a"].dataset
    unpooled = Config(sparse_turn_pool=None)
    model = fit(train.ranges, train.laser, taught, unpooled, spans, gt_poses(runs["a"]))
    for key in "ab":
        run = runs[key]
        poses = gt_poses(run)
        label = classify(model, run.dataset.ranges, poses).label
        turning = np.r_[np.hypot(*np.diff(poses[:, :2], axis=0).T) < 0.3, False]
        test = np.ones(len(label), dtype=bool)
        if key == "a":
            test[np.concatenate(list(taught.values()))] = False
        at = (run.labels == "corridor") & test
        assert np.mean(label[at & turning] == "corridor") < 0.3
        assert np.mean(label[at & ~turning] == "corridor") > 0.6
        assert np.mean(label[(run.labels == "room") & test] == "room") > 0.9


def test_brief_visits_lose_the_small_rooms_as_on_the_intel_log() -> None:
    """`--entered --brief` (session 26): the default finds the two large rooms (taught) and
    misses the small rooms entered briefly, as the Intel log's short visits into its small
    rooms (seed 1, measured: the short stays found in 0.00 / 0.00 of runs a / b, 17 scans
    each; the long stays 1.00 / 0.98)."""
    runs = worlds(1, 1.0, 0.5, entered=True, brief=True)
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    taught = training_indices(spans)
    model = fit(a.dataset.ranges, a.dataset.laser, taught, Config(), spans, gt_poses(a))
    for key in "ab":
        run = runs[key]
        label = classify(model, run.dataset.ranges, gt_poses(run)).label
        short = np.zeros(len(label), dtype=bool)
        for place, first, last in label_runs(run.labels):
            if place == "room" and last - first < 10:
                short[first : last + 1] = True
        assert short.sum() >= 12
        room = run.labels == "room"
        assert np.mean(label[room & short] == "room") < 0.3
        assert np.mean(label[room & ~short] == "room") > 0.95


def gt_poses(sim: object) -> np.ndarray:
    gt = sim.dataset.groundtruth  # type: ignore[attr-defined]
    return np.asarray(gt[["x", "y", "theta"]].to_numpy())


def found_shares(
    models: dict[Any, FeatureModel], run: Simulation, taught: dict[str, np.ndarray] | None
) -> dict[str, dict[Any, float]]:
    """Per model, the share found as their place of the run's short room stays (under ten
    scans; "stays"), of its corridor scans taken turning on the spot ("turns") and of its
    room scans ("rooms"); `taught`: the scans left out, run a's training ones."""
    poses = gt_poses(run)
    turning = np.r_[np.hypot(*np.diff(poses[:, :2], axis=0).T) < 0.3, False]
    test = np.ones(len(turning), dtype=bool)
    if taught is not None:
        test[np.concatenate(list(taught.values()))] = False
    short = np.zeros(len(test), dtype=bool)
    for place, first, last in label_runs(run.labels):
        if place == "room" and last - first < 10:
            short[first : last + 1] = True
    room, corridor = (run.labels == "room") & test, (run.labels == "corridor") & test
    found: dict[str, dict[Any, float]] = {"stays": {}, "turns": {}, "rooms": {}}
    for name, m in models.items():
        label = classify(m, run.dataset.ranges, poses).label
        stays = room & short  # none in some runs: NaN without numpy's empty-mean warning
        found["stays"][name] = float(np.mean(label[stays] == "room")) if stays.any() else np.nan
        found["turns"][name] = float(np.mean(label[corridor & turning] == "corridor"))
        found["rooms"][name] = float(np.mean(label[room] == "room"))
    return found


def test_turning_on_the_spot_counted_by_turn_length() -> None:
    """`turn_length` (m of path per rad turned in the HMM, 1 by default) and, on sparse logs,
    `sparse_turn_length` (session 25, turn25; off by default: on the Intel log it takes the
    rooms from 0.832 to 0.734; measured here without a turn pooled, session 26's default). With 0 a scan taken turning on the spot neither switches the
    place nor adds evidence, and takes its neighbours' label: on seed 0's entered worlds the
    corridor's turning scans are found in 0.89 / 0.67 of runs a / b (measured; 0.11 / 0.17
    by default), the rooms still 1.00."""
    turn = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [1.0, 0.0, 0.5]])
    assert path_steps(3, turn).tolist() == [np.inf, 0.5, 1.0]
    assert path_steps(3, turn, 0.0).tolist() == [np.inf, 0.0, 1.0]
    still = Config(turn_length=0.0)
    assert evidence_weights(still, 3, turn).tolist() == [1.0, 0.0, 1.0]
    assert switch_probability(still, 3, turn)[1] < switch_probability(Config(), 3, turn)[1] / 1e4
    runs = worlds(0, 1.0, 0.5, entered=True)
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    taught = training_indices(spans)
    models = {
        tl: fit(
            a.dataset.ranges,
            a.dataset.laser,
            taught,
            replace(BASE28, sparse_turn_length=tl, sparse_turn_pool=None),
            spans,
            gt_poses(a),
        )
        for tl in (None, 0.0)
    }
    assert models[None].config.turn_length == 1.0 and models[0.0].config.turn_length == 0.0
    for key, (before, after) in {"a": (0.2, 0.8), "b": (0.2, 0.6)}.items():
        found = found_shares(models, runs[key], taught if key == "a" else None)
        assert all(share > 0.95 for share in found["rooms"].values())
        assert found["turns"][None] < before and found["turns"][0.0] > after
    # a dense log keeps `turn_length` (sparse_turn_length is for sparse logs only)
    sim = simulate("random", seed=3)
    ds = sim.dataset
    spans = spans_from_frame(sim.regions, ds.t)
    dense = fit(
        ds.ranges,
        ds.laser,
        training_indices(spans),
        Config(sparse_turn_length=0.0),
        spans,
        gt_poses(sim),
    )
    assert dense.config.turn_length == 1.0


def test_a_turn_on_the_spot_pooled_into_one_view() -> None:
    """`turn_pool` / `sparse_turn_pool` (session 26, pool26; off by default: on the Intel log
    it takes the rooms under 0.8). The scans within the radius of a turn's first scan get the
    turn's pooled log-probabilities, weighing together what their translation weighs. On seed
    0's entered worlds (max over the turn, 0.3 m) the corridor's turning scans are found in
    0.67 / 0.67 of runs a / b (measured; 0.11 / 0.17 by default), the rooms still 1.00."""
    poses = np.array([[0, 0, 0], [0.05, 0, 0.5], [0.1, 0, 1.0], [1.1, 0, 1.0], [2.1, 0, 1.0]])
    assert turn_groups(poses, 0.3).tolist() == [0, 0, 0, 1, 2]
    assert turn_groups(poses, 1.5).tolist() == [0, 0, 0, 0, 1]
    nan = poses.copy()
    nan[1] = np.nan  # a scan without a pose is a turn of its own, and so is the one after it
    assert turn_groups(nan, 0.3).tolist() == [0, 1, 2, 3, 4]
    scores = np.log([[0.8, 0.2], [0.3, 0.7], [0.4, 0.6], [0.5, 0.5], [0.9, 0.1]])
    mean = pool_turns(Config(turn_pool=0.3, turn_pool_rule="mean"), scores, poses)
    share = (1.0 + 0.1 + 0.1) / 3  # the translation's evidence (0.05 m / 0.5 m), spread
    assert np.allclose(mean[:3], share * scores[:3].mean(axis=0))
    assert np.allclose(mean[3:], scores[3:])  # scans 1 m apart: as without pooling
    top = pool_turns(Config(turn_pool=0.3, turn_pool_rule="max"), scores, poses)
    assert np.allclose(top[:3], share * np.log([0.8, 0.7]))
    off = pool_turns(Config(), scores, poses)
    assert np.array_equal(off, scores * evidence_weights(Config(), 5, poses)[:, None])
    runs = worlds(0, 1.0, 0.5, entered=True)
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    taught = training_indices(spans)
    models = {
        pool: fit(
            a.dataset.ranges,
            a.dataset.laser,
            taught,
            replace(BASE28, sparse_turn_pool=pool, turn_pool_rule="max", turn_pool_reach=0.0),
            spans,
            gt_poses(a),
        )
        for pool in (None, 0.3)
    }
    assert models[None].config.turn_pool == 0.0 and models[0.3].config.turn_pool == 0.3
    for key in "ab":
        found = found_shares(models, runs[key], taught if key == "a" else None)
        assert all(share > 0.95 for share in found["rooms"].values())
        assert found["turns"][None] < 0.2 and found["turns"][0.3] > 0.6


def test_a_turn_pooled_only_where_it_sees_far() -> None:
    """`turn_pool_reach` (session 26, junction26; off by default). A turn is pooled only if a
    tenth of some scan's beams reach past the threshold (a junction, a way seen across); an
    enclosed turn keeps each scan's own evidence and weight. On seed 10's brief worlds (max
    over the turn, 0.3 m, reach 6 m) the small rooms' short stays keep what the default finds
    while the corridor's turning scans are found as with every turn pooled (seed 10,
    measured, runs a / b: short stays 1.00 / 1.00 by default, 0.74 / 0.88 every turn pooled,
    1.00 / 0.96 only the far-seeing ones; the corridor's turning scans 0.41 / 0.52, 0.85 /
    0.85 and 0.85 / 0.81)."""
    poses = np.array([[0, 0, 0], [0.05, 0, 0.5], [0.1, 0, 1.0], [1.1, 0, 1.0], [2.1, 0, 1.0]])
    scores = np.log([[0.8, 0.2], [0.3, 0.7], [0.4, 0.6], [0.5, 0.5], [0.9, 0.1]])
    close = np.full((5, 20), 2.0)
    far = close.copy()
    far[1, :3] = np.inf  # a tenth of one heading's beams without return: the turn sees far
    assert turn_reach(close, np.array([0, 3, 4])).tolist() == [2.0, 2.0, 2.0]
    assert turn_reach(far, np.array([0, 3, 4])).tolist() == [np.inf, 2.0, 2.0]
    far[1, 2] = 2.0  # two beams in twenty: under a tenth
    assert turn_reach(far, np.array([0, 3, 4]))[0] == 2.0
    far[1, 2] = 7.0
    cfg = replace(
        BASE28, turn_pool=0.3, turn_pool_rule="max", turn_pool_reach=6.0, turn_pool_door=0
    )
    pooled = pool_turns(Config(turn_pool=0.3, turn_pool_reach=0.0), scores, poses)
    own = scores * evidence_weights(cfg, 5, poses)[:, None]
    assert np.array_equal(pool_turns(cfg, scores, poses, close), own)  # enclosed: not pooled
    assert np.array_equal(pool_turns(cfg, scores, poses, far)[:3], pooled[:3])
    assert np.array_equal(pool_turns(cfg, scores, poses, far)[3:], own[3:])
    assert np.array_equal(
        pool_turns(replace(cfg, turn_pool_reach=0.0), scores, poses, close), pooled
    )
    assert np.array_equal(pool_turns(cfg, scores, poses), pooled)  # no ranges: every turn
    runs = worlds(10, 1.0, 0.5, entered=True, brief=True)
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    taught = training_indices(spans)
    model = fit(a.dataset.ranges, a.dataset.laser, taught, cfg, spans, gt_poses(a))
    assert model.config.turn_pool == 0.3 and model.config.turn_pool_reach == 6.0
    models = {
        "default": replace(model, config=replace(model.config, turn_pool=0.0)),
        "every turn": replace(model, config=replace(model.config, turn_pool_reach=0.0)),
        "far": model,
    }
    for key in "ab":
        found = found_shares(models, runs[key], taught if key == "a" else None)
        stays, turns = found["stays"], found["turns"]
        assert stays["far"] > 0.95 and stays["every turn"] < 0.9 and stays["default"] > 0.95
        assert turns["far"] > turns["default"] + 0.25


def test_a_far_turn_beside_an_enclosed_one_is_not_pooled() -> None:
    """`turn_pool_door` (session 27, places27; 2 by default). With `turn_pool_reach`, a
    far-seeing turn with an enclosed turn among the k turns before or after it (the turn at a
    doorway, beside a room's first or last scans) keeps each scan's own evidence and weight
    too. On seed 12's brief worlds (max 0.3 m, reach 6 m) it keeps the small rooms' short
    stays the default finds, which junction26's rule loses, and keeps most of the corridor's
    turning scans' gain (seed 12, measured, runs a / b: short stays 1.00 / 0.94 by default,
    0.80 / 0.94 with reach 6 alone, 1.00 / 0.94 with k 1 and with k 2; the corridor's turning
    scans 0.83 / 0.21, 1.00 / 0.42, 1.00 / 0.42 and 0.91 / 0.33)."""
    # a driven scan, a turn of three on the spot that sees far, one enclosed driven scan, one far
    poses = np.array(
        [[0, 0, 0], [1, 0, 0], [1.05, 0, 0.5], [1.1, 0, 1.0], [2.1, 0, 1.0], [3.1, 0, 1.0]]
    )
    scores = np.log([[0.8, 0.2], [0.3, 0.7], [0.4, 0.6], [0.9, 0.1], [0.5, 0.5], [0.6, 0.4]])
    ranges = np.full((6, 20), 8.0)
    ranges[4] = 2.0  # the scan after the turn sees only close walls: an enclosed turn of one
    reach = Config(turn_pool=0.3, turn_pool_rule="max", turn_pool_reach=6.0, turn_pool_door=0)
    door = replace(reach, turn_pool_door=1)
    own = scores * evidence_weights(reach, 6, poses)[:, None]
    by_reach = pool_turns(reach, scores, poses, ranges)
    assert not np.array_equal(by_reach[1:4], own[1:4])  # reach alone: the turn is pooled
    assert np.array_equal(pool_turns(door, scores, poses, ranges), own)  # beside: not pooled
    ranges[4] = 8.0  # nothing enclosed beside the turn: pooled as by reach alone
    assert np.array_equal(pool_turns(door, scores, poses, ranges), by_reach)
    ranges[5] = 2.0  # enclosed two turns after it: pooled with k 1, not with k 2
    assert np.array_equal(pool_turns(door, scores, poses, ranges)[1:4], by_reach[1:4])
    two = pool_turns(replace(door, turn_pool_door=2), scores, poses, ranges)
    assert np.array_equal(two[1:4], own[1:4])
    every = replace(door, turn_pool_reach=0.0)  # every turn pooled: no turn is enclosed
    assert np.array_equal(
        pool_turns(every, scores, poses, ranges), pool_turns(every, scores, poses)
    )
    with pytest.raises(ToolkitError, match="turn_pool_door -1: turns, 0 or more"):
        Config(turn_pool_door=-1)
    runs = worlds(12, 1.0, 0.5, entered=True, brief=True)
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    taught = training_indices(spans)
    model = fit(a.dataset.ranges, a.dataset.laser, taught, BASE28, spans, gt_poses(a))
    assert model.config.turn_pool == 0.3 and model.config.turn_pool_door == 2  # the default
    models = {
        name: replace(model, config=replace(model.config, place_pool=0.0, **kw))  # session 27's
        for name, kw in (
            ("none", {"turn_pool": 0.0}),
            ("reach", {"turn_pool_door": 0}),
            ("door", {"turn_pool_door": 1}),
            ("door 2", {}),
        )
    }  # fmt: skip
    for key in "ab":
        found = found_shares(models, runs[key], taught if key == "a" else None)
        stays, turns = found["stays"], found["turns"]
        assert stays["door"] == stays["door 2"] == stays["none"] > 0.9
        assert turns["door"] > turns["door 2"] > turns["none"] + 0.08
        if key == "a":
            assert stays["reach"] < 0.9


def test_a_junctions_long_turn_is_pooled_beside_an_enclosed_turn() -> None:
    """`turn_pool_junction` (session 28, junc28; 7 scans by default). A turn on the spot of at
    least N scans whose far beams point down two ways out 60 degrees apart or more (a
    junction) is pooled even where `turn_pool_door` refuses it (an enclosed turn beside it);
    a long turn with one way out (a room seen out of its door), or a shorter turn, is not.
    On seed 3's brief world with crossings, run c, the crossings' long turns are found more
    (measured 0.30 off -> 1.00 with N 7, the default)."""
    angles = np.deg2rad(np.arange(36) * 10.0)  # a laser all round, a beam per 10 degrees
    theta = np.r_[0.0, 0.5 * np.arange(8), 3.5, 3.5]
    poses = np.c_[[0.0, *[1.0] * 8, 2.0, 3.0], np.zeros(11), theta]
    heading = np.rad2deg(np.mod(theta[:, None] + angles[None, :], 2 * np.pi))
    way = np.abs(((heading[..., None] - np.array([0.0, 90.0])) + 180) % 360 - 180) <= 25
    ranges = np.where(way.any(axis=-1), 8.0, 2.0)
    ranges[[0, 9, 10]] = 2.0  # driven scans beside the turn, enclosed
    scores = np.log(np.linspace(0.2, 0.8, 11)[:, None] * [1.0, -1.0] + [0.0, 1.0])
    cfg = Config(turn_pool=0.3, turn_pool_reach=6.0, turn_pool_door=2, turn_pool_junction=0)
    first = np.array([0, 1, 9, 10])
    assert junction_turns(ranges, poses, angles, first, 6.0, 7).tolist() == [0, 1, 0, 0]
    assert not junction_turns(ranges, poses, angles, first, 6.0, 9).any()  # 8 scans: short
    own = pool_turns(cfg, scores, poses, ranges, angles)  # the door rule refuses the turn
    assert np.array_equal(own, scores * evidence_weights(cfg, 11, poses)[:, None])
    junction = replace(cfg, turn_pool_junction=7)
    pooled = pool_turns(junction, scores, poses, ranges, angles)
    door_off = pool_turns(replace(cfg, turn_pool_door=0), scores, poses, ranges, angles)
    assert np.array_equal(pooled[1:9], door_off[1:9])  # pooled as without the door rule
    assert np.array_equal(pooled[[0, 9, 10]], own[[0, 9, 10]])
    assert np.array_equal(pool_turns(junction, scores, poses, ranges), own)  # no angles: off
    one = np.where(way[..., 0], 8.0, 2.0)  # one way out only: a room seen out of its door
    one[[0, 9, 10]] = 2.0
    assert not junction_turns(one, poses, angles, first, 6.0, 7).any()
    assert np.array_equal(
        pool_turns(junction, scores, poses, one, angles),
        pool_turns(cfg, scores, poses, one, angles),
    )
    with pytest.raises(ToolkitError, match="turn_pool_junction -1: scans, 0 or more"):
        Config(turn_pool_junction=-1)
    runs = worlds(3, 1.0, 0.5, entered=True, brief=True, crossings=True)
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    taught = training_indices(spans)
    model = fit(a.dataset.ranges, a.dataset.laser, taught, BASE28, spans, gt_poses(a))
    assert model.config.turn_pool_junction == 7  # the default
    c = runs["c"]
    poses_c, truth = gt_poses(c), np.asarray(c.labels)
    group = turn_groups(poses_c, 0.3)
    long = (np.bincount(group)[group] >= 7) & (truth == "corridor")
    found = {
        n: np.mean(classify(replace(model, config=replace(model.config, turn_pool_junction=n)), c.dataset.ranges, poses_c).label[long] == "corridor")
        for n in (0, 7)
    }  # fmt: skip
    assert long.sum() >= 14 and found[0] < 0.5 and found[7] > 0.9


def test_the_view_ahead_described_on_a_sparse_log() -> None:
    """`sparse_view_ahead` (session 29, axis29; on by default). On a sparse log the trees
    also take the view ahead (`view_ahead`: the end points' major axis, the ranges' mean and
    spread, the histogram, the forward sectors), which tell a corridor seen across from a
    junction's turn from a room (Intel AUC 0.91 for the major axis, long turns against room
    scans); a dense log keeps its columns. The open set's claims leave the view ahead out:
    with it, brief world 8 with crossings claimed 0.29 of its log, learnt none and called
    0.65 of run a's corridor none (measured: claims 0.544 as the default's, corridor 0.99).
    On seed 3's world with crossings, run b, the crossings' long turns are found more
    (measured 0.53 off -> 0.84), the rooms no less (0.95 -> 0.97)."""
    runs = worlds(8, 1.0, 0.5, entered=True, brief=True, crossings=True)
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    taught = training_indices(spans)
    on, off = Config(), Config(sparse_view_ahead=False)
    model = fit(a.dataset.ranges, a.dataset.laser, taught, on, spans, gt_poses(a))
    before = fit(a.dataset.ranges, a.dataset.laser, taught, off, spans, gt_poses(a))
    assert model.config.view_ahead and not before.config.view_ahead
    assert model.fit_report["open_set"] == before.fit_report["open_set"]
    assert "no 'none' learnt" in model.fit_report["open_set"]
    truth = np.asarray(a.labels)
    label = classify(model, a.dataset.ranges, gt_poses(a)).label
    assert np.mean(label[truth == "corridor"] == "corridor") > 0.9
    dense = simulate("random", seed=3)
    spans = spans_from_frame(dense.regions, dense.dataset.t)
    kept = fit(
        dense.dataset.ranges,
        dense.dataset.laser,
        training_indices(spans),
        on,
        spans,
        gt_poses(dense),
    )
    assert not kept.config.view_ahead  # a dense log: the place columns alone
    runs = worlds(3, 1.0, 0.5, entered=True, brief=True, crossings=True)
    a, b = runs["a"], runs["b"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    taught = training_indices(spans)
    poses_b, truth = gt_poses(b), np.asarray(b.labels)
    group = turn_groups(poses_b, 0.3)
    long = (np.bincount(group)[group] >= 7) & (truth == "corridor")
    found = {}
    for name, cfg in (("on", on), ("off", off)):
        model = fit(a.dataset.ranges, a.dataset.laser, taught, cfg, spans, gt_poses(a))
        label = classify(model, b.dataset.ranges, poses_b).label
        found[name] = (
            np.mean(label[long] == "corridor"),
            np.mean(label[truth == "room"] == "room"),
        )
    assert long.sum() >= 14 and found["on"][0] > found["off"][0] + 0.2
    assert found["on"][1] >= found["off"][1]


def test_the_view_ahead_without_its_near_bins_keeps_a_thinned_hall() -> None:
    """`view_ahead_near_bins` False (an expert setting, session 29, thin29): the trees take the
    view ahead without its range histogram's bins under 2 m. In thinned world 12 the hall is
    taught from 10 scans, and with those bins the hall of the other world (run c) is lost
    (measured BA 0.95 with the view ahead off, 0.50 with it, 0.95 without the near bins); the
    corridor of runs a and b stays found. Session 31's default (a second classifier without
    the near bins for the far-seeing turns, the mean of the two) finds a part of it (0.60)."""
    runs = worlds(12, 1.0)
    assert teaches_two(runs)
    one = Config(view_ahead_near_enclosed=False)  # session 30's default: one classifier
    with_bins = protocol_scores(one, runs, taught_only=True)
    near_off = protocol_scores(replace(one, view_ahead_near_bins=False), runs, taught_only=True)
    assert with_bins["c"]["ba"] < 0.55 and near_off["c"]["ba"] > 0.9
    assert near_off["a"]["recall"]["corridor"] > 0.95 and near_off["b"]["ba"] > 0.9
    default = protocol_scores(Config(), runs, taught_only=True)
    assert with_bins["c"]["ba"] + 0.05 < default["c"]["ba"] < near_off["c"]["ba"] - 0.2


def test_the_near_bins_kept_only_for_enclosed_turns_keeps_a_small_room(tmp_path: Path) -> None:
    """`view_ahead_near_enclosed` (session 30, near30; the default since session 31): the
    scans of turns that see far are scored by a second classifier without the view ahead's
    near bins too. In brief crossing world 2000 the view ahead without its near bins loses the
    small rooms entered briefly (run a, rooms found: measured 0.959 with one classifier, 0.673
    without the bins); the second classifier alone keeps them (0.959), since the robot turns
    in them enclosed, and finds more corridor (0.884 -> 0.913). The second classifier travels
    in the saved model."""
    runs = worlds(2000, 1.0, 0.5, True, True, False, True)
    one = Config(view_ahead_near_enclosed=False)  # session 30's default
    default = protocol_scores(one, runs, taught_only=True)
    near_off = protocol_scores(replace(one, view_ahead_near_bins=False), runs, taught_only=True)
    enclosed = protocol_scores(Config(view_ahead_near_average=False), runs, taught_only=True)
    room = {
        k: v["a"]["recall"]["room"] for k, v in (("d", default), ("o", near_off), ("e", enclosed))
    }
    assert room["o"] < room["d"] - 0.1 and room["e"] > room["o"] + 0.1
    assert enclosed["a"]["recall"]["corridor"] > default["a"]["recall"]["corridor"]
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    poses = a.dataset.groundtruth[["x", "y", "theta"]].to_numpy()
    config = Config(view_ahead_near_average=False)
    model = fit(a.dataset.ranges, a.dataset.laser, training_indices(spans), config, spans, poses)
    assert model.places_far is not None
    again = FeatureModel.load(model.save(tmp_path / "model.json"))
    assert again.places_far is not None
    assert np.array_equal(
        classify(model, a.dataset.ranges, poses).prob, classify(again, a.dataset.ranges, poses).prob
    )
    # `view_ahead_near_average` (avg30, the default since session 31): on the far-seeing
    # turns the mean of the two classifiers' probabilities, elsewhere the first's untouched
    own = class_scores(model, a.dataset.ranges, CHUNK, None, poses)
    alone = near_enclosed(model, a.dataset.ranges, poses, own, CHUNK)
    model.config = replace(model.config, view_ahead_near_average=True)
    mean = near_enclosed(model, a.dataset.ranges, poses, own, CHUNK)
    far = np.any(alone != own, axis=1)
    assert far.sum() > 10 and np.array_equal(mean[~far], own[~far])
    assert np.allclose(np.exp(mean[far]), (softmax(alone[far]) + softmax(own[far])) / 2)


def test_the_second_classifier_left_out_at_doorways_keeps_the_rooms_last_scans() -> None:
    """`view_ahead_near_door_free` (an expert setting, session 31, reach31): with
    `view_ahead_near_enclosed`, the far-seeing turns next to an enclosed one (within
    `turn_pool_door` turns: a room's door) keep the first classifier. In brief crossing world
    10 the second classifier on every far-seeing turn takes a small room's last scans, at its
    door, to the corridor (run a, rooms found: measured 0.964 with one classifier, session
    30's default, 0.927 with the second alone on every far-seeing turn); left out at the
    doorways the rooms are one classifier's (0.964),
    and the transfer world's corridor is still found more (run c: 0.861 -> 0.911)."""
    runs = worlds(10, 1.0, 0.5, True, True, False, True)
    one = Config(view_ahead_near_enclosed=False)  # session 30's default: one classifier
    default = protocol_scores(one, runs, taught_only=True)
    alone = Config(view_ahead_near_average=False)  # the second classifier alone, as measured
    config = replace(alone, view_ahead_near_door_free=True)
    everywhere = protocol_scores(alone, runs, taught_only=True)
    door_free = protocol_scores(config, runs, taught_only=True)
    room = {k: v["a"]["recall"]["room"] for k, v in (("d", default), ("e", everywhere))}
    assert door_free["a"]["recall"]["room"] == room["d"] > room["e"]
    assert door_free["c"]["recall"]["corridor"] > default["c"]["recall"]["corridor"] + 0.03
    # the scans it changes: those of far-seeing turns with no enclosed turn beside them
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    poses = a.dataset.groundtruth[["x", "y", "theta"]].to_numpy()
    model = fit(a.dataset.ranges, a.dataset.laser, training_indices(spans), config, spans, poses)
    own = class_scores(model, a.dataset.ranges, CHUNK, None, poses)
    gated = np.any(near_enclosed(model, a.dataset.ranges, poses, own, CHUNK) != own, axis=1)
    model.config = replace(model.config, view_ahead_near_door_free=False)
    far = np.any(near_enclosed(model, a.dataset.ranges, poses, own, CHUNK) != own, axis=1)
    group, first = turns(poses, model.config.turn_pool)
    far_turn = turn_reach(a.dataset.ranges, first) > model.config.turn_pool_reach
    enclosed_next = ~far_turn[np.clip(group + 1, 0, len(first) - 1)]
    assert gated.sum() > 10 and not (gated & ~far).any() and not (gated & enclosed_next).any()
    assert (far & ~gated).sum() > 0
