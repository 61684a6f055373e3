"""Scan descriptors and the place classifier on them: what they claim to be invariant to, and
what they learn from ten scans per place on a random world."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from toolkit.features import PAPER, Config, FeatureModel, classify, fit
from toolkit.features.descriptors import (
    context_ahead,
    context_windows,
    describe,
    features,
    names,
    path_length,
    place_columns,
    with_context,
)
from toolkit.features.evaluate import MOZOS, protocol_scores, worlds
from toolkit.features.metrics import balanced_accuracy
from toolkit.features.places import (
    SUPPORT_NEIGHBOURS,
    Forest,
    PlaceClassifier,
    fit_places,
    resemblance,
    support_rows,
)
from toolkit.features.regions import spans_from_frame, training_indices
from toolkit.sim import simulate


@pytest.fixture(scope="module")
def world():  # type: ignore[no-untyped-def]
    return simulate("random", seed=3)


def test_descriptors_are_named_finite_and_the_same_mirrored(world) -> None:  # type: ignore[no-untyped-def]
    ds = world.dataset
    x = describe(ds.ranges, ds.laser)
    assert x.shape == (ds.n_scans, len(names()))
    assert np.isfinite(x).all()
    # a door on the left on the way out is a door on the right on the way back
    mirrored = describe(ds.ranges[:, ::-1], ds.laser)
    used = place_columns()
    assert np.allclose(x[:, used], mirrored[:, used], atol=1e-6)
    # the place's descriptors leave out the view ahead, and keep the free width beside
    kept = [names()[i] for i in used]
    assert "log_width_beside" in kept and not any("0_15deg" in n for n in kept)
    # nor the no-returns that see glass ahead (session 14); the lateral ones stay
    assert "return_fraction" not in kept and "no_return_45_60deg_max" not in kept
    assert "no_return_75_90deg_max" in kept


def test_descriptor_model_learns_places_the_paper_model_does_not(world, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    ds = world.dataset
    spans = spans_from_frame(world.regions, ds.t)
    training = training_indices(spans)
    test = np.ones(ds.n_scans, dtype=bool)
    test[np.concatenate(list(training.values()))] = False
    poses = ds.groundtruth[["x", "y", "theta"]].to_numpy()
    scores = {}
    for name, config in (("default", Config()), ("paper", PAPER)):
        model = fit(ds.ranges, ds.laser, training, config, spans)
        labels = classify(model, ds.ranges, poses)
        scores[name] = balanced_accuracy(world.labels[test], labels.label[test])
        if name == "default":
            assert model.places is not None and model.places.classes == model.names
            again = FeatureModel.load(model.save(tmp_path / "model.json"))
            assert np.allclose(classify(again, ds.ranges, poses).prob, labels.prob)
    assert scores["default"] > 0.75  # seed 3: 0.86 (the former default 0.6-0.7)
    assert scores["default"] > scores["paper"] + 0.3


def test_compiled_finish_equals_the_numpy_reference(world) -> None:  # type: ignore[no-untyped-def]
    from toolkit.features import descriptors as d

    ds = world.dataset
    seen: dict[str, np.ndarray] = {}
    accumulate = d._accumulate

    def keep(*args):  # type: ignore[no-untyped-def]
        accumulate(*args)
        seen["sums"], seen["sectors"], seen["beside"] = args[-3], args[-2], args[-1]

    d._accumulate = keep  # type: ignore[assignment]
    try:
        x = describe(ds.ranges, ds.laser)
    finally:
        d._accumulate = accumulate
    ref = d._finish(seen["sums"], seen["sectors"], seen["beside"], ds.n_beams)
    assert np.allclose(x, ref, rtol=0, atol=1e-9)


def test_context_is_the_mean_and_spread_over_the_path_window(world) -> None:  # type: ignore[no-untyped-def]
    ds = world.dataset
    poses = ds.groundtruth[["x", "y", "theta"]].to_numpy()
    along = path_length(ds.n_scans, poses)
    cols = place_columns()
    whole = features(ds.ranges, ds.laser, cols, along, 1.0)
    x = describe(ds.ranges, ds.laser)[:, cols]
    d = len(cols)
    for i in (0, 17, ds.n_scans // 2, ds.n_scans - 1):
        near = np.abs(along - along[i]) <= 1.0
        assert np.allclose(whole[i, :d], x[i])
        assert np.allclose(whole[i, d : 2 * d], x[near].mean(axis=0), atol=1e-9)
        assert np.allclose(whole[i, 2 * d :], x[near].std(axis=0), atol=1e-6)
    # scored in blocks (as classify does), a block's windows reach into its neighbours
    rows = slice(100, 300)
    block = features(ds.ranges, ds.laser, cols, along, 1.0, rows)
    assert np.allclose(block, whole[rows], rtol=0, atol=1e-6)  # sums' rounding in the spread
    lo, hi = context_windows(along, 1.0)
    assert (hi - lo).min() >= 2 and np.array_equal(with_context(x, lo, hi), whole)


def test_forest_as_arrays_equals_scikit_learn(world) -> None:  # type: ignore[no-untyped-def]
    from sklearn.ensemble import ExtraTreesClassifier

    ds = world.dataset
    x = describe(ds.ranges, ds.laser)
    y = np.asarray(world.labels).astype(str)
    trees = ExtraTreesClassifier(20, min_samples_leaf=2, random_state=0).fit(x[::3], y[::3])
    ours = Forest.from_dict(Forest.from_sklearn(trees).to_dict())
    assert np.allclose(ours.predict_proba(x), trees.predict_proba(x), atol=1e-12)


def test_views_apart_are_their_own_class_and_summed_into_their_place() -> None:
    """`fit_places(apart=...)`: copies labelled "a (seen turned)" are a class of the trees
    and not of the model (its classes are the places), their shares added to "a": a scan
    like them is "a" (and the log's scans like them are self-trained as "a"), the leaves'
    shares still sum to 1. Without `apart` the views' shares are no place's."""
    rng = np.random.default_rng(0)
    x = np.vstack([rng.normal(0.0, 1.0, (20, 3)), rng.normal(5.0, 1.0, (20, 3))])
    y = np.array(["a"] * 20 + ["b"] * 20)
    groups = np.repeat([0, 1, 2, 3], 10)
    seen = rng.normal(12.0, 1.0, (20, 3))  # the views: far from both places
    extra = (seen, np.full(20, "a (seen turned)"), np.ones(20))
    log = np.vstack([x, rng.normal(12.0, 1.0, (30, 3))])
    model = fit_places(
        x, y, groups, unlabelled=log, extra=extra, apart={"a (seen turned)": "a"},
        open_set="never",
    )  # fmt: skip
    assert model.classes == ["a", "b"]
    assert model.forest is not None and np.allclose(model.forest.value.sum(axis=1), 1.0)
    p = np.exp(model.log_proba(rng.normal(12.0, 1.0, (10, 3)), none=False))
    assert (p[:, 0] > 0.8).all()
    alone = fit_places(x, y, groups, extra=extra, open_set="never")  # not summed into "a"
    assert (np.exp(alone.log_proba(rng.normal(12.0, 1.0, (10, 3)), none=False))[:, 0] < 0.6).all()


@pytest.mark.parametrize("seed", [50])  # not a tuning seed (0-29) nor a held-out one (100-119)
def test_default_travels_better_than_the_mozos_baseline(seed: int) -> None:
    """Taught on one run of a world it was not tuned on: the rest of the run (a), the way back
    (b) and another world (c)."""
    runs = worlds(seed)
    ours, mozos = (protocol_scores(config, runs) for config in (Config(), MOZOS))
    assert ours["a"]["ba"] > 0.8 and ours["b"]["ba"] > 0.75 and ours["c"]["ba"] > 0.6
    assert ours["a"]["ece"] < 0.15 and ours["b"]["ece"] < 0.15
    mean = lambda r: np.mean([r[k]["ba"] for k in "abc"])  # noqa: E731
    assert mean(ours) > mean(mozos) + 0.05
    # the strip beside the laser narrowed from 1 m to 0.45 m: fewer false doors on this
    # world (door precision 0.69 / 0.77 against 0.62 / 0.67), every run as well or better
    # (both without the reach in metres, which came after and narrows the difference, and
    # with the context window of the time, 1 m of scans either side: session 12's window
    # reaches the context less the strip ahead, nothing with a 1 m strip; and with the
    # no-returns ahead, `glass_ahead`, as until session 14; widths in metres, as until
    # session 18; no resemblance check, as until session 20; a door call far from an
    # opening beside the laser kept, as until session 24: with `beside_reach` both 0.953)
    old = Config(
        absolute_reach=False,
        context_seen=False,
        glass_ahead=True,
        canonical_width=0.0,
        resemble=0.0,
        augment_starts=0.0,
        augment_ends=0.0,
        beside_reach=0.0,
        narrow_opening=0.0,
    )
    narrow = protocol_scores(old, runs)
    wide = protocol_scores(dataclasses.replace(old, beside=1.0), runs)
    for k in "ab":
        assert narrow[k]["precision"]["door"] > wide[k]["precision"]["door"] + 0.03
    assert all(narrow[k]["ba"] >= wide[k]["ba"] for k in "abc")
    # (c) not: with the canonical width (session 18) this world's other world loses most of
    # its doors (recall 0.94 -> 0.36, balanced accuracy 0.975 -> 0.864; the rooms behind a
    # door do not widen with the corridor, their depth is rescaled with it)
    assert all(ours[k]["ba"] >= wide[k]["ba"] for k in "ab")


def test_the_reach_in_metres_finds_a_hall_of_the_other_kind() -> None:
    """Taught on a world whose hall opens on both sides (seed 2), applied to another world
    whose hall opens on one side (protocol c): in units of the free width beside the laser
    the two look nothing alike (the one-sided hall's near wall is a corridor's), and without
    the reach in metres none of that hall is found (measured 0.00); with it, most of it
    (0.68). Without the taught scans' closed copies, which find it without the reach too,
    and with the context window of the time (1 m of scans either side; with session 12's,
    without the copies, the reach alone finds none of it: 0.00). With the no-returns ahead
    (`glass_ahead`, until session 14: without them, 0.58 of that hall is found without the
    reach). With the widths in metres, as until session 18 (with the canonical width the
    reach alone finds 0.20 of it; the default, with the copies, 0.97). With the trees of the
    time (`leaf_weight` 0, session 21: with 0.5, the reach finds 0.50 of it)."""
    runs = worlds(2)
    found = {
        absolute: protocol_scores(
            Config(
                absolute_reach=absolute,
                augment_closed=0.0,
                context_seen=False,
                glass_ahead=True,
                canonical_width=0.0,
                leaf_weight=0.0,
                resemble=1.0,
                augment_starts=0.0,
                augment_ends=0.0,
            ),
            runs,
        )["c"]["recall"]["hall"]
        for absolute in (True, False)
    }
    assert found[False] < 0.2
    assert found[True] > 0.5


@pytest.mark.parametrize("seed", [46])  # not a tuning seed (0-29) nor a held-out one
def test_closed_copies_find_a_hall_of_the_other_kind(seed: int) -> None:
    """Taught on a world whose hall opens on both sides, applied to another world whose hall
    opens on one side (protocol c): without the taught scans' copies with the less open side
    walled, none of that hall is found (measured 0.00, balanced accuracy 0.578); with them
    most of it (0.95, 0.763). The same world's runs (a), (b) within 0.02. With the context
    window of the time (1 m of scans either side) and without the opened copies (session 13's
    default: with them, 0.58 of that hall is found without the closed copies); with session
    12's window, the hall is found in 0.63 of its scans without the copies. With the widths
    in metres, as until session 18 (with the canonical width, 0.68 without the copies). With
    the trees of the time (`leaf_weight` 0: with session 21's 0.5 the hall is found in 0.35 of
    its scans without the copies). Without the ended copies (`augment_ends`, session 23's
    default: they find this hall without the closed copies). The default finds all of it."""
    runs = worlds(seed)
    old = Config(
        context_seen=False,
        augment_open=0.0,
        glass_ahead=True,
        canonical_width=0.0,
        leaf_weight=0.0,
        resemble=1.0,
        augment_ends=0.0,
    )
    without = protocol_scores(dataclasses.replace(old, augment_closed=0.0), runs)
    with_copies = protocol_scores(old, runs)
    assert without["c"]["recall"]["hall"] < 0.2
    assert with_copies["c"]["recall"]["hall"] > 0.8
    assert with_copies["c"]["ba"] > without["c"]["ba"] + 0.1
    assert all(with_copies[k]["ba"] > without[k]["ba"] - 0.03 for k in "ab")
    assert protocol_scores(Config(), runs)["c"]["recall"]["hall"] > 0.8


@pytest.mark.parametrize("seed", [55])  # a development seed of session 13 (50-69)
def test_opened_copies_find_a_hall_of_the_other_kind(seed: int) -> None:
    """Taught on a world whose hall opens on one side of its corridor, applied to another
    world whose hall opens on both (protocol c): without the taught scans' copies with the
    less open side opened, none of that hall is found (measured 0.00, balanced accuracy
    0.578); with them almost all of it (0.98, 0.818). The same world's runs gain too
    ((a) 0.795 -> 0.821, (b) 0.818 -> 0.849; docs/journal/places.md, session 13). With the
    no-returns ahead (`glass_ahead`, session 13's descriptors: without them the hall is found
    in 0.54 of its scans without the opened copies). With the trees of the time (`leaf_weight`
    0: with session 21's 0.5, 0.27 of the hall is found without the opened copies)."""
    runs = worlds(seed)
    old = Config(
        glass_ahead=True, leaf_weight=0.0, resemble=1.0, augment_starts=0.0, augment_ends=0.0
    )
    with_copies = protocol_scores(old, runs)
    without = protocol_scores(dataclasses.replace(old, augment_open=0.0), runs)
    assert without["c"]["recall"]["hall"] < 0.2
    assert with_copies["c"]["recall"]["hall"] > 0.8
    assert with_copies["c"]["ba"] > without["c"]["ba"] + 0.15
    assert all(with_copies[k]["ba"] > without[k]["ba"] for k in "ab")


@pytest.mark.parametrize("seed", [57])  # a development seed of session 12 (50-79)
def test_context_seen_either_side_calls_fewer_scans_before_a_door_doors(seed: int) -> None:
    """A 180-degree scanner sees beside it only ahead of the laser, so a context window of
    1 m of scans either side sees 1.45 m ahead and 1 m behind: the scans up to 0.6 m before
    a door's zone were called door. The window that reaches 0.55 m ahead (`context_seen`)
    sees 1 m either side. Measured on this world: door precision (a) 0.52 -> 0.79, (b) 0.53
    -> 0.94, balanced accuracy (a) 0.931 -> 0.962, (b) 0.943 -> 0.972, (c) 0.685 -> 0.672.
    Without the opened copies (session 12's default; with them, session 13's, the door's
    precision (a) is 0.39 -> 0.53), and with the no-returns ahead (`glass_ahead`, until
    session 14: without them 0.54 -> 0.64)."""
    runs = worlds(seed)
    # as at the time: no resemblance check (session 20), which drops most of the same doors,
    # and the door calls far from an opening beside the laser kept (`beside_reach`, session
    # 24, which drops the rest: (a) 0.74 against 0.62 with it)
    then = Config(
        augment_open=0.0,
        glass_ahead=True,
        resemble=0.0,
        augment_starts=0.0,
        augment_ends=0.0,
        beside_reach=0.0,
        narrow_opening=0.0,
    )
    seen = protocol_scores(then, runs)
    scans = protocol_scores(dataclasses.replace(then, context_seen=False), runs)
    for k in "ab":
        assert seen[k]["precision"]["door"] > scans[k]["precision"]["door"] + 0.2
        assert seen[k]["recall"]["door"] > 0.9
    assert all(seen[k]["ba"] > scans[k]["ba"] + 0.02 for k in "ab")
    assert seen["c"]["ba"] > scans["c"]["ba"] - 0.03


def test_context_reaches_less_ahead_for_a_scanner_that_sees_only_ahead(world) -> None:  # type: ignore[no-untyped-def]
    """180 degrees: the strip beside the laser lies ahead of it, the window reaches the
    context less the strip ahead; a scanner that sees behind itself gets the symmetric one."""
    laser = world.dataset.laser
    assert context_ahead(1.0, 0.45, laser) == pytest.approx(0.55)
    wide = dataclasses.replace(laser, angle_min=-2.0, angle_increment=4.0 / (laser.beams - 1))
    assert context_ahead(1.0, 0.45, wide) == 1.0
    along = np.arange(100) * 0.1
    lo, hi = context_windows(along, 1.0, None, 0.55)
    assert (lo[50], hi[50]) == (40, 56)


@pytest.mark.parametrize("seed", [4])
def test_without_the_no_returns_ahead_fewer_scans_before_a_window_are_windows(seed: int) -> None:
    """The whole scan's return fraction and the no-return share at 30-60 degrees see glass
    0.5-2 m before the robot is beside it (`GLASS_AHEAD`); without them (the default since
    session 14) the window's precision on this world rises in (a) 0.70 -> 0.87, its recall
    stays above 0.95, and the balanced accuracy rises (a) 0.972 -> 0.988, (b) 0.973 -> 0.984."""
    runs = {k: v for k, v in worlds(seed).items() if k in "ab"}
    # without the resemblance check (session 20), which drops most of the same windows
    # and without the copies of session 23 (`augment_starts`, `augment_ends`) and session
    # 24's door and hall calls only near an opening beside the laser (`beside_reach`)
    then = Config(
        resemble=0.0, augment_starts=0.0, augment_ends=0.0, beside_reach=0.0, narrow_opening=0.0
    )
    now = protocol_scores(then, runs)
    ahead = protocol_scores(dataclasses.replace(then, glass_ahead=True), runs)
    assert now["a"]["precision"]["window"] > ahead["a"]["precision"]["window"] + 0.12
    assert min(now[k]["recall"]["window"] for k in "ab") > 0.95
    assert all(now[k]["ba"] > ahead[k]["ba"] + 0.005 for k in "ab")


@pytest.mark.parametrize("seed", [19])
def test_self_training_on_the_stays_cores_calls_fewer_scans_doors(seed: int) -> None:
    """`stay_edge` 0.5 (an expert setting, session 19): the trees' door stays in the training
    log are self-trained without their ends, so the door's edge is not learnt outwards. Seed
    19: the door's precision (a) 0.745 -> 1.00, its recall 1.00 -> 0.95, balanced accuracy
    (a) 0.970 -> 0.965 (it fails with `stay_edge=0`)."""
    runs = {"a": simulate("random", seed=seed)}
    # without the resemblance check (session 20: door precision 0.83 here), the ended
    # copies (session 23: 0.84 here) and the calls only near a short opening beside the
    # laser (session 24: 0.95 here without `stay_edge`), as measured then
    then = Config(resemble=0.0, augment_ends=0.0, beside_reach=0.0, narrow_opening=0.0)
    now = protocol_scores(then, runs)["a"]
    cores = protocol_scores(dataclasses.replace(then, stay_edge=0.5), runs)["a"]
    assert now["precision"]["door"] < 0.8 and cores["precision"]["door"] > 0.95
    assert cores["recall"]["door"] > 0.9
    assert cores["ba"] > now["ba"] - 0.01


def test_forest_leaves_and_proximity_equal_scikit_learn(world) -> None:  # type: ignore[no-untyped-def]
    """`Forest.leaves` is scikit-learn's `apply` (offset by each tree's first node), and the
    proximity of a scan to a place is the share of trees putting it in one leaf with a
    support scan of the place, the mean over its `SUPPORT_NEIGHBOURS` closest (numpy)."""
    from sklearn.ensemble import ExtraTreesClassifier

    ds = world.dataset
    x = describe(ds.ranges, ds.laser)
    y = np.asarray(world.labels).astype(str)
    trees = ExtraTreesClassifier(20, min_samples_leaf=2, random_state=0).fit(x[::3], y[::3])
    forest = Forest.from_sklearn(trees)
    cols = np.arange(x.shape[1])
    mean, scale = np.zeros(x.shape[1]), np.ones(x.shape[1])
    leaves = forest.leaves(x, cols, mean, scale)
    assert np.array_equal(leaves, trees.apply(x) + forest.roots)
    classes = list(dict.fromkeys(y))
    rows, where = support_rows(y[::3], classes)
    model = PlaceClassifier(
        classes, cols, mean, scale, np.zeros((len(classes), 0)), np.zeros(len(classes)),
        np.zeros((len(classes), 1)), np.eye(1), 0.0, forest=forest,
        support_leaves=leaves[::3][rows], support_place=where,
    )  # fmt: skip
    model = PlaceClassifier.from_dict(model.to_dict())  # the support is saved with the model
    got = model.proximity(x[:300])
    shared = (leaves[:300, None, :] == leaves[::3][rows][None, :, :]).mean(axis=2)
    want = np.stack(
        [np.sort(shared[:, where == j], axis=1)[:, -SUPPORT_NEIGHBOURS:].mean(axis=1)
         for j in range(len(classes))], axis=1,
    )  # fmt: skip
    assert np.allclose(got, want)
    own = np.array([classes.index(k) for k in y[:300]])
    assert np.mean(got.argmax(axis=1) == own) > 0.9  # a scan is closest to its own place


def test_resemblance_moves_only_the_calls_unlike_the_logs_own() -> None:
    """Only a checked place called in enough scans is penalised, and only its scans whose
    proximity is under `RESEMBLE_MARGIN` times the median of its calls: by the log of the
    shortfall times the slope."""
    k = 3
    logp = np.log(np.full((10, k + 1), 0.1))
    logp[:8, 1] = 0.0  # eight calls of place 1, two of place 0
    logp[8:, 0] = 0.0
    proximity = np.full((10, k), 0.5)
    proximity[:6, 1] = 0.8  # the median of place 1's calls is 0.8
    proximity[6, 1] = 0.7 * 0.8  # at the margin: kept
    proximity[7, 1] = 0.1
    out = resemblance(logp, proximity, np.array([0, 1]), 2.0)
    assert out.shape == (10, k) and (out <= 0).all()
    assert (out[:, [0, 2]] == 0).all()  # place 0: too few calls; place 2: not checked
    assert np.allclose(out[:7, 1], 0.0)
    assert out[7, 1] == pytest.approx(-2.0 * np.log(0.7 * 0.8 / 0.1))
    assert out[8, 1] == pytest.approx(-2.0 * np.log(0.7 * 0.8 / 0.5))  # a scan not called 1


@pytest.mark.parametrize("seed", [116])
def test_a_door_called_only_where_the_scan_resembles_the_trees_doors(seed: int) -> None:
    """The resemblance check (`resemble`, the default since session 20): the door calls the
    trees do not put in one leaf with their own door scans as often as the log's door calls
    are dropped. Seed 116 (a development world): the door's precision (a) 0.28 -> 0.69, its
    recall stays 1.00, the window's precision 0.88 -> 0.93, balanced accuracy (a) 0.863 ->
    0.948 (it fails with `resemble=0`). With the door calls far from an opening beside the
    laser kept, as until session 24 (`beside_reach` 0: with it the door's precision without
    the check is 0.50)."""
    runs = {"a": simulate("random", seed=seed)}
    now = protocol_scores(Config(beside_reach=0.0, narrow_opening=0.0), runs)["a"]
    before = protocol_scores(Config(resemble=0.0, beside_reach=0.0, narrow_opening=0.0), runs)["a"]
    assert before["precision"]["door"] < 0.35 and now["precision"]["door"] > 0.6
    assert now["recall"]["door"] > 0.95
    assert now["precision"]["window"] > before["precision"]["window"] + 0.02
    assert now["ba"] > before["ba"] + 0.05
