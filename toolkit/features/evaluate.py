"""Evaluation: the train / test protocol on random worlds, its ablation, and the scores on the
simulator's fixed scenarios.

The protocol (issue 16): for each seed, teach on one run through a random world (its regions:
ten scans per place, in one or two spans, as a user picks them) and score

    (a) the rest of that run (every scan but the training ones),
    (b) a second run through the same world, the other way round, at another speed and
        lateral offset (`route=1`),
    (c) another world of the generator with the same place kinds (seed + 1000): transfer,

each against the true place of every scan: balanced accuracy (mean and 10th percentile over
the seeds), top-label ECE, and precision and recall per place (means over the seeds). Each
row of the ablation adds one part to the one before; the default row is `Config()`.

    python -m toolkit.features.evaluate [--seeds 100-119] [--scenarios] [--spacing 1.0]
        [--turn 0.5] [--entered] [--brief] [--revisit] [--crossings] [--out table.md]
    python -m toolkit.features.evaluate --seeds 0-19,2000-2019 --paired '{"context": 0}'

`--paired` measures one change: the default and the variant on the same worlds, each measure's
change per world averaged, with twice its standard error (a change beyond it is told from the
worlds' spread; the sessions' journals quote these tables).

With `--spacing` (m) every run is thinned to scans that far apart along the true path, as
in a log whose scans are far apart (the Intel log's are about 1 m apart, and the sparse-scan
rule, `fitting._sparse`, fires on such logs): run a's regions are chosen again among its
kept scans (ten per place, `training_regions`, so only places of 10 m of path or more are
taught), only the scans of taught places are scored (as on the Intel log, whose check
scores its corridor and rooms), and the seeds whose run a teaches fewer than two places are
left out (the table says how many are used). `--turn` (rad) also keeps a scan at every turn
of that much, as the Intel log's does (0.5 rad) on its turns on the spot.

With `--entered` the paths also enter rooms (`random_world(..., entered=True)`) and every run
is labelled and taught as the Intel log is (`as_intel`): corridor (its doorways, windows and
crossings included) and room, two spans of ten scans each; only those are scored. `--brief`
(with `--entered`) makes the rooms but two small and entered briefly, as the Intel lab's
short visits (`random_world(..., brief=True)`). `--revisit` makes every path come back along
the chain to its start (`random_world(..., revisit=True)`; session 28): each stretch of
corridor seen twice, once each way, as the Intel robot sees its ring; the regions stay on the
way out, so (a) scores the rest of the run, the way back included. `--crossings` puts one or
two side corridors across the chain (`random_world(..., crossings=True)`; session 28): the
paths spin on the spot where they cross, as the Intel robot at its ring's junctions.

The default seeds, 100-119, were the first held-out set. Each session since has held out a
fresh set, run only to measure and then spent for development (300-319, 400-419, 500-519,
600-619, 700-719, 800-819, 900-919, 2000-2019, 2020-2039, 2040-2059, 2060-2079, 2080-2099, 2100-2119,
2120-2139, 2140-2159; docs/places.md): a new held-out figure needs seeds never run before, their
transfer worlds (seed + 1000) included (2160 and up)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict, Unpack

import numpy as np
import pandas as pd

from toolkit.features.classify import classify
from toolkit.features.fitting import fit
from toolkit.features.metrics import (
    balanced_accuracy,
    expected_calibration_error,
    per_class_recall,
)
from toolkit.features.model import PAPER, SURROUNDINGS, Config
from toolkit.features.regions import spans_from_frame, training_indices
from toolkit.sim import Simulation, simulate
from toolkit.sim.procedural import random_world
from toolkit.sim.truth import REGION_PARTS, REGION_SCANS, training_regions
from toolkit.sim.truth import runs as label_runs
from toolkit.typed import int_ranges

FULL = Config()
BEAMS = Config(descriptors=False)  # the per-beam model alone (the former default)
LATERAL2 = dataclasses.replace(SURROUNDINGS, lateral_weight=2.0)  # bench: as its spans choose
# the chain of defaults (rows 4-7) measures widths in metres until the last step
LOGISTIC = dataclasses.replace(
    FULL, classifier="logistic", context=0.0, beam_term=1.0, canonical_width=0.0
)
# the peer baseline: Mozos et al.'s descriptors as they measure (no canonical width)
MOZOS = dataclasses.replace(FULL, mozos=True, context=0.0, canonical_width=0.0)
ABLATION: list[tuple[str, Config]] = [
    ("paper: per-beam Gaussians, Eq. 8-9 literal (--paper)", PAPER),
    ("per-beam model, robust, none = world, HMM (--none-model world)", BEAMS),
    ("per-beam model, --none-model surroundings", SURROUNDINGS),
    ("Mozos et al. 2005 descriptors alone, same classifier (trees), no context: the peer baseline", MOZOS),
    ("last default: place descriptors, logistic regression + temperature, self-training, none gate, per-beam term 1, HMM", LOGISTIC),
    ("- the per-beam term", dataclasses.replace(LOGISTIC, beam_term=0.0)),
    ("+ extremely randomised trees instead of the regression (no temperature)", dataclasses.replace(FULL, context=0.0, canonical_width=0.0)),
    ("+ context: the descriptors' mean and spread over 1 m of path either side; each log's widths across the path rescaled to a usual free width of 2 m (canonical_width)", FULL),
    ("alternative: Mozos et al. 2005 descriptors + context", dataclasses.replace(MOZOS, context=FULL.context)),
    ("alternative: without the HMM (per scan)", dataclasses.replace(FULL, smoothing="none")),
    ("alternative: without self-training", dataclasses.replace(FULL, self_training=0)),
    ("alternative: without the none gate", dataclasses.replace(FULL, none_class=False)),
    ("alternative: + per-beam term weight 0.3", dataclasses.replace(FULL, beam_term=0.3)),
    ("alternative: context 0.5 m", dataclasses.replace(FULL, context=0.5)),
    ("alternative: closed set, no learnt none (--open-set never)", dataclasses.replace(FULL, open_set="never")),
    ("alternative: open set always (--open-set always)", dataclasses.replace(FULL, open_set="always")),
    ("alternative: the strip beside the laser 1 m (the last session's; default 0.45 m)", dataclasses.replace(FULL, beside=1.0)),
    ("alternative: leaf shares not mixed with uniform (leaf_mix 0, the last session's; default 0.1)", dataclasses.replace(FULL, leaf_mix=0.0)),
    ("alternative: no context, the local map over 2 m of path instead (the descriptors logs with sparse scans get; their HMM also has two stages)", dataclasses.replace(FULL, context=0.0, local_map=FULL.sparse_local_map)),
    ("alternative: + the local map over 2 m of path beside the context", dataclasses.replace(FULL, local_map=FULL.sparse_local_map)),
    ("alternative: without the reach beside the laser in metres (two sessions ago)", dataclasses.replace(FULL, absolute_reach=False)),
    ("alternative: without the taught scans' closed copies (augment_closed 0; the opened ones stay)", dataclasses.replace(FULL, augment_closed=0.0)),
    ("alternative: without the taught scans' opened copies (augment_open 0: session 12's default)", dataclasses.replace(FULL, augment_open=0.0)),
    ("alternative: the context 1 m of scans either side (context_seen off: session 11's default)", dataclasses.replace(FULL, context_seen=False)),
    ("alternative: + the no-returns ahead of the place (glass_ahead: the return fraction, the no-return share at 30-60 degrees; session 13's default)", dataclasses.replace(FULL, glass_ahead=True)),
    ("alternative: + the HMM's dwell of two stages per place (dwell_stages 2: a place lasts two switching lengths, a stay of a few scans is unlikely)", dataclasses.replace(FULL, dwell_stages=2)),
    ("alternative: + the opening beside the robot (opening: the gap's length along the path and its depth, from the scans around)", dataclasses.replace(FULL, opening=True)),
    ("alternative: + the opening and the dwell of two stages", dataclasses.replace(FULL, opening=True, dwell_stages=2)),
    ("alternative: + the opening and the dwell of three stages", dataclasses.replace(FULL, opening=True, dwell_stages=3)),
    ("alternative: the open set's claims of session 16 (also on the whole-scan shape, quantile 0.1)", dataclasses.replace(FULL, claim_shape=True, claim_quantile=0.1)),
    ("alternative: each log stretched across the path to a usual free width of 2 m for the descriptors (canonical_width 2, canonical_how stretch: session 17)", dataclasses.replace(FULL, canonical_width=2.0, canonical_how="stretch")),
    ("alternative: widths in metres as measured, no canonical width (canonical_width 0: the default until session 18)", dataclasses.replace(FULL, canonical_width=0.0)),
    ("alternative: self-training only on the scans more than 0.5 m of path inside their stay (stay_edge 0.5: session 19)", dataclasses.replace(FULL, stay_edge=0.5)),
    ("alternative: stay_edge 0.5 and the opening beside the robot (session 19)", dataclasses.replace(FULL, stay_edge=0.5, opening=True)),
    ("alternative: without the resemblance check (resemble 0: the default until session 20; a door or window call unlike the trees' own door or window scans keeps its share)", dataclasses.replace(FULL, resemble=0.0)),
    ("alternative: session 20's default (leaf_weight 0: self-trained scans alone may form a leaf; resemble 1)", dataclasses.replace(FULL, leaf_weight=0.0, resemble=1.0)),
    ("alternative: + the reach beside the laser also in metres, not rescaled (reach_metres: session 22)", dataclasses.replace(FULL, reach_metres=True)),
    ("alternative: without the taught hall's and corner's copies as at their ends (augment_ends 0: ends23's default, session 23)", dataclasses.replace(FULL, augment_ends=0.0)),
    ("alternative: session 22's default (augment_starts 0, augment_ends 0: no copies of the taught hall as from the corridor just outside it, nor as at its ends)", dataclasses.replace(FULL, augment_starts=0.0, augment_ends=0.0)),
    ("alternative: session 23's default (beside_reach 0, narrow_opening 0, across_of and glass_to empty: neither the opening rules, nor the copies walled across, nor the window call by a room going to the door)", dataclasses.replace(FULL, beside_reach=0.0, narrow_opening=0.0, across_of=(), glass_to=())),
    ("alternative: without the opening rules (beside_reach 0, narrow_opening 0: a door or hall call far from an opening beside the laser, and a door call by a long one, kept; margin24, session 24)", dataclasses.replace(FULL, beside_reach=0.0, narrow_opening=0.0)),
    ("alternative: without the copies walled across (across_of empty: a taught door across from a window keeps its closed and opened copies, the window labelled door; miss24, session 24)", dataclasses.replace(FULL, across_of=())),
    ("alternative: + the taught door's copies with a window across (augment_glass 1: session 24)", dataclasses.replace(FULL, augment_glass=1.0)),
    ("alternative: the opening rules' places named, not learnt (beside_places door and hall, narrow_places door: margin24's, session 24)", dataclasses.replace(FULL, beside_places=("door", "hall"), narrow_places=("door",))),
    ("alternative: without the window call by a room going to the door (glass_to empty: a window call where the square beams see a room beside the laser kept; glass24, session 24)", dataclasses.replace(FULL, glass_to=())),
    ("alternative: the glass and room places named, not learnt (glass_to window and door: glass24's, session 24)", dataclasses.replace(FULL, glass_to=("window", "door"))),
    ("alternative: without the door's zone past its opening (room_margin 0: a corridor or window call with the door runner-up near a door call that sees a room beside kept; door25, session 25)", dataclasses.replace(FULL, room_margin=0.0)),
    ("alternative: session 24's default (glass_to window and door, room_margin 0)", dataclasses.replace(FULL, glass_to=("window", "door"), room_margin=0.0)),
    ("alternative: + on a sparse log, a scan taken turning on the spot neither switches the place nor adds evidence in the HMM, no turn pooled (sparse_turn_length 0, sparse_turn_pool None; turn25, session 25)", dataclasses.replace(FULL, sparse_place_pool=None, sparse_turn_length=0.0, sparse_turn_pool=None)),
    ("alternative: + on a sparse log, each turn on the spot (the scans within 0.3 m of its first) pooled in the HMM: per place the largest log-probability over the turn, the turn weighing what its translation weighs, every turn (sparse_turn_pool 0.3, turn_pool_rule max, turn_pool_reach 0; pool26, session 26)", dataclasses.replace(FULL, sparse_place_pool=None, turn_pool_junction=0, sparse_turn_pool=0.3, turn_pool_rule="max", turn_pool_reach=0.0, turn_pool_door=0)),
    ("alternative: + on a sparse log, pool26's pooled turn (sparse_turn_pool 0.3, turn_pool_rule max) only where the turn sees far, a tenth of some scan's beams past 6 m; an enclosed turn as without pooling, a turn at a doorway pooled (turn_pool_reach 6, turn_pool_door 0; junction26, session 26)", dataclasses.replace(FULL, sparse_place_pool=None, turn_pool_junction=0, sparse_turn_pool=0.3, turn_pool_rule="max", turn_pool_reach=6.0, turn_pool_door=0)),
    ("alternative: + on a sparse log, junction26's pooled turn (sparse_turn_pool 0.3, turn_pool_rule max, turn_pool_reach 6) not pooled either where only the previous or next turn is enclosed (turn_pool_door 1, the default 2; places27, session 27)", dataclasses.replace(FULL, sparse_place_pool=None, turn_pool_junction=0, sparse_turn_pool=0.3, turn_pool_rule="max", turn_pool_reach=6.0, turn_pool_door=1)),
    ("alternative: session 26's default, no turn pooled on a sparse log (sparse_turn_pool None; the default pools a turn that sees far past 6 m with no enclosed turn among the two before or after it: turn_pool_door 2, places27, session 27)", dataclasses.replace(FULL, sparse_turn_pool=None, sparse_place_pool=None)),
    ("alternative: session 27's default, no revisit pooled on a sparse log (sparse_place_pool None, turn_pool_junction 0; the default gives a junction's turn on the spot, seeing past 6 m with no enclosed turn among the two before or after it, the evidence of the other passes' scans within the 3 x 3 cells of 4 m around it: space28, session 28)", dataclasses.replace(FULL, sparse_place_pool=None, turn_pool_junction=0)),
    ("alternative: + on a sparse log, the taught scans also taught as seen from their poses turned on the spot by 45 and 90 degrees either way, rendered from the scans around their span (augment_turned 1, turned_by 45, -45, 90, -90, turned_spans all; aug28, session 28: the corridor found far more, the rooms less)", dataclasses.replace(FULL, augment_turned=1.0)),
    ("alternative: the default without the junction rule, a junction's long turn not pooled beside an enclosed turn (turn_pool_junction 0; the default pools a turn of 7 scans or more on the spot that sees past 6 m down two ways out 60 degrees apart in spite of turn_pool_door: junc28, session 28)", dataclasses.replace(FULL, turn_pool_junction=0)),
    ("alternative: the default without the view ahead on a sparse log (sparse_view_ahead off, session 28's default; the default also describes there the end points' major axis, the ranges' mean and spread, the range histogram, the forward sectors: a corridor seen across from a junction's turn still spans metres along it, axis29, session 29)", dataclasses.replace(FULL, sparse_view_ahead=False)),
    ("alternative: on a sparse log, the far-seeing turns scored by the second classifier (without the view ahead's near bins) alone, not the mean of the two (view_ahead_near_average False: near30, session 30; the mean is the default since session 31)", dataclasses.replace(FULL, view_ahead_near_average=False)),
    ("alternative: session 30's default, one place classifier on a sparse log (view_ahead_near_enclosed False: the default gives the turns that see past 6 m the mean of it and a second classifier without the view ahead's range-histogram bins under 2 m; near30 and avg30, session 30, the default since session 31)", dataclasses.replace(FULL, view_ahead_near_enclosed=False)),
    ("alternative: on a sparse log, the second classifier alone (not the mean) and only on the far-seeing turns not at a doorway, no enclosed turn among the two before or after (view_ahead_near_door_free, view_ahead_near_average False, turn_pool_door: a room's last scans at its door keep the first classifier; reach31, session 31)", dataclasses.replace(FULL, view_ahead_near_average=False, view_ahead_near_door_free=True)),
]  # fmt: skip
TRANSFER = 1000  # protocol (c): the world of seed + this
DEVELOPMENT_SEEDS = tuple(range(10))
HELD_OUT_SEEDS = tuple(range(100, 120))


@dataclass
class Score:
    balanced_accuracy: float
    ece: float
    accuracy: float
    scans: int
    recall: dict[str, float]
    temperature: float
    lateral_weight: float
    seconds: float


def score(
    scenario: str,
    config: Config,
    seed: int = 0,
    sim: Simulation | None = None,
    parts: int = REGION_PARTS,
) -> Score:
    """Train on the simulator's regions (`parts` spans per feature), classify the whole log,
    score the other scans."""
    if sim is None:
        sim = simulate(scenario, seed=seed)
    ds = sim.dataset
    regions = training_regions(ds.t, sim.labels, parts=parts, along=sim.distance())
    spans = spans_from_frame(regions, ds.t)
    training = training_indices(spans)
    t0 = time.perf_counter()
    if ds.groundtruth is None:
        raise ValueError("the simulation has no ground truth")
    poses = ds.groundtruth[["x", "y", "theta"]].to_numpy()
    model = fit(ds.ranges, ds.laser, training, config, spans, poses)
    labels = classify(model, ds.ranges, poses)
    seconds = time.perf_counter() - t0
    test = np.ones(len(ds.t), dtype=bool)
    test[np.concatenate(list(training.values()))] = False
    truth, predicted = np.asarray(sim.labels)[test], labels.label[test]
    correct = truth == predicted
    return Score(
        balanced_accuracy=balanced_accuracy(truth, predicted),
        ece=expected_calibration_error(labels.confidence[test], correct),
        accuracy=float(correct.mean()),
        scans=int(test.sum()),
        recall=per_class_recall(truth, predicted),
        temperature=model.temperature,
        lateral_weight=float(model.config.lateral_weight or 0.0),
        seconds=seconds,
    )


def worlds(
    seed: int,
    spacing: float = 0.0,
    turn: float = 0.0,
    entered: bool = False,
    brief: bool = False,
    revisit: bool = False,
    crossings: bool = False,
) -> dict[str, Any]:
    """The three runs of the protocol for one seed: a (teach and score), b (same world,
    other route), c (another world); with `spacing` > 0 each thinned (`thinned`, also at
    every `turn` rad turned when > 0); with `entered` the paths enter rooms and the runs are
    labelled and taught as the Intel log is (`as_intel`); with `brief` too, small rooms
    entered briefly beside two entered fully; with `revisit`, paths that come back to their
    start; with `crossings`, worlds with side corridors where the paths spin
    (`random_world`)."""
    more: dict[str, bool] = {"entered": True} if entered else {}
    if brief:
        more["brief"] = True
    if revisit:
        more["revisit"] = True
    if crossings:
        more["crossings"] = True
    runs = {
        "a": simulate("random", seed=seed, **more),
        "b": simulate("random", seed=seed, route=1, **more),
        "c": simulate("random", seed=seed + TRANSFER, **more),
    }
    # with `revisit`: the time each run reaches the end of its way out (the turn-around)
    ends = (
        {k: way_out_end(v, entered, brief, crossings) for k, v in runs.items()} if revisit else {}
    )
    if spacing > 0:
        runs = {k: thinned(v, spacing, turn) for k, v in runs.items()}
    return {k: as_intel(v, ends.get(k)) for k, v in runs.items()} if entered else runs


def way_out_end(sim: Simulation, entered: bool, brief: bool, crossings: bool = False) -> float:
    """The time a path that comes back (`revisit`) reaches its way out's end: its first scan
    there (the way out is the path of the same world and route without `revisit`)."""
    p = sim.params
    end = random_world(sim.seed, p["route"], entered, brief, crossings=crossings).waypoints[-1]
    gt = sim.dataset.groundtruth
    assert gt is not None
    there = np.hypot(*(gt[["x", "y"]].to_numpy() - end).T) < 1e-6
    if not there.any():
        raise ValueError("the path does not reach its way out's end: not a revisit path")
    return float(sim.dataset.t[int(np.argmax(there))])


def thinned(sim: Simulation, spacing: float, turn: float = 0.0) -> Simulation:
    """The run with only the scans at least `spacing` m of true path after the last one kept
    or, with `turn` > 0, at least `turn` rad of turning after it (the Intel log keeps a scan
    every 1 m or 0.5 rad: on its turns on the spot too), the first scan kept; its regions
    chosen again among them (`Simulation.take`)."""
    along = sim.distance()
    gt = sim.dataset.groundtruth
    assert gt is not None
    turned = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(np.unwrap(gt["theta"]))))])
    keep = [0]
    while True:  # a step per kept scan
        i = int(np.searchsorted(along, along[keep[-1]] + spacing, side="left"))
        if turn > 0:
            i = min(i, int(np.searchsorted(turned, turned[keep[-1]] + turn, side="left")))
        if i >= len(along):
            break
        keep.append(i)
    note = {"spacing": spacing, **({"turn": turn} if turn > 0 else {})}
    return sim.take(np.array(keep), **note)


#: With `entered`: the places of the corridor's own stretch are "corridor", as the Intel
#: check's position rule calls its ring (the rooms' doorways, windows and crossings).
AS_CORRIDOR = ("door", "window", "corner")


def as_intel(sim: Simulation, until: float | None = None) -> Simulation:
    """The run labelled and taught as the Intel log is: "corridor" for the corridor's whole
    stretch (`AS_CORRIDOR`), "room" inside rooms, the hall kept (not taught, so not scored);
    the corridor taught from two spans of ten scans driven straight along two of its runs,
    the rooms from ten scans in each of two rooms (the README's intel-regions.csv); a place
    with one such run has its two spans there, at a quarter and three quarters of it. With
    `until` (a time), the spans are chosen among the scans up to then (a path that comes
    back: its way out, whose last corridor run would otherwise run on into the way back)."""
    labels = np.where(np.isin(sim.labels, AS_CORRIDOR), "corridor", sim.labels)
    gt = sim.dataset.groundtruth
    assert gt is not None
    xy = gt[["x", "y"]].to_numpy()
    step = np.hypot(*np.diff(xy, axis=0).T)
    driving = np.concatenate([[False], step > 0.5 * (step.max() if len(step) else 0.0)])
    t = sim.dataset.t
    until = t[-1] if until is None else until
    rows = []
    for place in ("corridor", "room"):
        found = []  # per run of the place: the first scans of its windows of ten
        for label, first, last in label_runs(labels[: np.searchsorted(t, until, "right")]):
            if label != place or last - first + 1 < REGION_SCANS:
                continue
            ok = driving[first : last + 1] if place == "corridor" else np.ones(last - first + 1)
            good = np.convolve(ok, np.ones(REGION_SCANS), "valid") == REGION_SCANS
            if good.any():
                found.append(first + np.flatnonzero(good))
        if len(found) >= 2:  # the middle window of the first two runs
            chosen = [int(w[len(w) // 2]) for w in found[:2]]
        elif found:
            w = found[0]
            chosen = [int(w[len(w) // 4]), int(w[3 * len(w) // 4])]
            if chosen[1] - chosen[0] < REGION_SCANS:
                chosen = [int(w[len(w) // 2])]
        else:
            chosen = []
        rows += [(place, float(t[i]), float(t[i + REGION_SCANS - 1])) for i in chosen]
    regions = pd.DataFrame(rows, columns=["feature", "start", "end"])
    return dataclasses.replace(sim, labels=labels, regions=regions)


def protocol_scores(
    config: Config, runs: dict[str, Any], taught_only: bool = False
) -> dict[str, dict[str, Any]]:
    """Teach on run a's regions; per run a, b, c: balanced accuracy, ECE, precision and
    recall per place (a: the scans other than the training ones; `taught_only`: only the
    scans whose true place was taught)."""
    train = runs["a"]
    ds = train.dataset
    spans = spans_from_frame(train.regions, ds.t)
    training = training_indices(spans)
    poses = ds.groundtruth[["x", "y", "theta"]].to_numpy()
    model = fit(ds.ranges, ds.laser, training, config, spans, poses)
    out = {}
    for key, sim in runs.items():
        d = sim.dataset
        labels = classify(model, d.ranges, d.groundtruth[["x", "y", "theta"]].to_numpy())
        test = np.ones(d.n_scans, dtype=bool)
        if key == "a":
            test[np.concatenate(list(training.values()))] = False
        if taught_only:
            test &= np.isin(sim.labels, list(training))
        truth, predicted = np.asarray(sim.labels)[test], labels.label[test]
        out[key] = {
            "ba": balanced_accuracy(truth, predicted),
            "ece": expected_calibration_error(labels.confidence[test], truth == predicted),
            "recall": per_class_recall(truth, predicted),
            "precision": {
                str(c): float(np.mean(truth[predicted == c] == c))
                for c in np.unique(truth)
                if (predicted == c).any()
            },
            "none": float(np.mean(predicted == "none")),
        }
    return out


def teaches_two(runs: dict[str, Any]) -> bool:
    """Whether run a's regions teach two places or more (a thinned run may teach one)."""
    return bool(runs["a"].regions["feature"].nunique() >= 2)


class WorldKind(TypedDict, total=False):
    """`worlds`' options after the seed, as `protocol` passes them on."""

    spacing: float
    turn: float
    entered: bool
    brief: bool
    revisit: bool
    crossings: bool


def _partial(kind: WorldKind) -> bool:
    """Whether the worlds of `kind` score only their taught places (thinned or entered)."""
    return kind.get("spacing", 0.0) > 0 or kind.get("entered", False)


def _per_world(
    configs: list[Config], seeds: tuple[int, ...], kind: WorldKind
) -> Iterator[tuple[int, list[dict[str, dict[str, Any]]]]]:
    """Per seed whose worlds of `kind` count (`teaches_two` where only taught places are
    scored): the seed and `protocol_scores` of each configuration on the same runs."""
    partial = _partial(kind)
    for seed in seeds:
        runs = worlds(seed, **kind)
        if partial and not teaches_two(runs):
            continue
        yield seed, [protocol_scores(config, runs, taught_only=partial) for config in configs]


def protocol(
    configs: list[tuple[str, Config]], seeds: tuple[int, ...], **kind: Unpack[WorldKind]
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The protocol's table (a row per configuration) and, for the first configuration
    marked default (else the first), precision and recall per place and run, on the worlds
    of `kind` (`worlds`' options). With `spacing` (and `turn`) the runs are thinned, with
    `entered` they enter rooms and are taught as the Intel log; then only taught places are
    scored, and seeds teaching fewer than two places left out."""
    results: dict[str, list[dict[str, dict[str, Any]]]] = {name: [] for name, _ in configs}
    partial = _partial(kind)
    for _, scores in _per_world([config for _, config in configs], seeds, kind):
        for (name, _), score in zip(configs, scores, strict=True):
            results[name].append(score)
    rows = []
    for name, config in configs:
        per_seed = results[name]
        row: dict[str, Any] = {"model": name + (" (default)" if config == FULL else "")}
        if partial:
            row["seeds"] = len(per_seed)
        for key in "abc":
            ba = np.array([r[key]["ba"] for r in per_seed])
            row[f"({key}) BA mean"] = round(float(ba.mean()), 3)
            row[f"({key}) BA P10"] = round(float(np.percentile(ba, 10)), 3)
        for key in "abc":
            row[f"({key}) ECE"] = round(float(np.mean([r[key]["ece"] for r in per_seed])), 3)
        for key in "abc":  # the "precision of every place": its lowest place
            precision = _mean_per_place(per_seed, key, "precision")
            lowest = min(precision.values()) if precision else float("nan")
            row[f"({key}) min precision"] = round(lowest, 3)
        row["(a) none share"] = round(float(np.mean([r["a"]["none"] for r in per_seed])), 3)
        rows.append(row)
    chosen = next((n for n, c in configs if c == FULL), configs[0][0])
    places = []
    for key in "abc":
        precision = _mean_per_place(results[chosen], key, "precision")
        recall = _mean_per_place(results[chosen], key, "recall")
        for place in sorted(recall):
            places.append(
                {
                    "run": key,
                    "place": place,
                    "precision": round(precision.get(place, float("nan")), 3),
                    "recall": round(recall[place], 3),
                }
            )
    return pd.DataFrame(rows), pd.DataFrame(places)


def paired(
    variant: Config, seeds: tuple[int, ...], **kind: Unpack[WorldKind]
) -> tuple[pd.DataFrame, list[dict[str, Any]]]:
    """The default against `variant`, paired per world on the worlds of `kind`: per run a, b,
    c and measure (balanced accuracy, ECE, each place's recall), the mean of the worlds'
    changes (variant minus default) with twice its standard error, and the worlds where the
    two score alike; and the per-world scores themselves. Paired, a change of a few scans is
    told from the worlds' spread, which two protocol tables side by side cannot do."""
    per_world: list[dict[str, Any]] = [
        {"seed": seed, "default": default, "variant": changed}
        for seed, (default, changed) in _per_world([FULL, variant], seeds, kind)
    ]
    rows = []
    for key in "abc":
        pairs = [(w["default"][key], w["variant"][key]) for w in per_world]
        measures: dict[str, list[tuple[float, float]]] = {
            "BA": [(d["ba"], v["ba"]) for d, v in pairs],
            "ECE": [(d["ece"], v["ece"]) for d, v in pairs],
        }
        for place in sorted({p for d, _ in pairs for p in d["recall"]}):
            measures[f"{place} recall"] = [
                (d["recall"][place], v["recall"][place])
                for d, v in pairs
                if place in d["recall"] and place in v["recall"]
            ]
        for name, values in measures.items():
            before, after = np.array(values).T if values else (np.zeros(0), np.zeros(0))
            change = after - before
            spread = 2 * change.std(ddof=1) / np.sqrt(len(change)) if len(change) > 1 else np.nan
            rows.append(
                {
                    "run": key,
                    "measure": name,
                    "worlds": len(change),
                    "default": round(float(before.mean()), 4) if len(change) else np.nan,
                    "variant": round(float(after.mean()), 4) if len(change) else np.nan,
                    "change": round(float(change.mean()), 4) if len(change) else np.nan,
                    "2 SE": round(float(spread), 4),
                    "equal": int(np.sum(change == 0)),
                }
            )
    return pd.DataFrame(rows), per_world


def _mean_per_place(per_seed: list[dict[str, Any]], key: str, what: str) -> dict[str, float]:
    values: dict[str, list[float]] = {}
    for r in per_seed:
        for place, v in r[key][what].items():
            values.setdefault(place, []).append(v)
    return {p: float(np.mean(v)) for p, v in values.items()}


def scenarios_table(
    configs: list[tuple[str, Config]],
    seed: int = 0,
    names: tuple[str, ...] = ("corridor", "building"),
) -> pd.DataFrame:
    """Balanced accuracy and ECE on the simulator's fixed scenarios, a row per configuration."""
    sims = {s: simulate(s, seed=seed) for s in names}
    rows = []
    for name, config in configs:
        row: dict[str, Any] = {"model": name + (" (default)" if config == FULL else "")}
        for s in names:
            r = score(s, config, seed, sims[s])
            row[f"{s} BA"] = round(r.balanced_accuracy, 3)
            row[f"{s} ECE"] = round(r.ece, 3)
            row[f"{s} min recall"] = round(min(r.recall.values()), 3)
        rows.append(row)
    return pd.DataFrame(rows)


def markdown(table: pd.DataFrame, digits: int = 3) -> str:
    """A pipe table (no extra dependency)."""
    cols = [str(c) for c in table.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for row in table.itertuples(index=False):
        lines.append(
            "| "
            + " | ".join(f"{v:.{digits}f}" if isinstance(v, float) else str(v) for v in row)
            + " |"
        )
    return "\n".join(lines)


def _variant(text: str) -> Config:
    """A JSON object of Config fields over the default."""
    fields = json.loads(text)
    if not isinstance(fields, dict):
        raise argparse.ArgumentTypeError("a JSON object of Config fields, e.g. '{\"context\": 0}'")
    known = {f.name for f in dataclasses.fields(Config)}
    unknown = sorted(set(fields) - known)
    if unknown:
        raise argparse.ArgumentTypeError(f"no Config field {unknown[0]!r}")
    return dataclasses.replace(FULL, **fields)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "--seeds", type=int_ranges, default=HELD_OUT_SEEDS, help="e.g. 100-119 (default) or 0-9"
    )
    parser.add_argument("--rows", type=int_ranges, help="only these ablation rows (0-based)")
    parser.add_argument(
        "--scenarios", action="store_true", help="also the corridor and building scenarios (seed 0)"
    )
    parser.add_argument(
        "--spacing",
        type=float,
        default=0.0,
        help="m: thin every run to scans this far apart (e.g. 1.0, as the Intel log's)",
    )
    parser.add_argument(
        "--turn",
        type=float,
        default=0.0,
        help="rad: with --spacing, also keep a scan at every this much turning (the Intel log: 0.5)",
    )
    parser.add_argument(
        "--entered",
        action="store_true",
        help="paths that enter rooms, labelled and taught as the Intel log (corridor and room)",
    )
    parser.add_argument(
        "--brief",
        action="store_true",
        help="with --entered: small rooms entered briefly, as the Intel lab's (a step in, a look, out)",
    )
    parser.add_argument(
        "--revisit",
        action="store_true",
        help="paths that come back along the corridors to their start (every stretch seen twice)",
    )
    parser.add_argument(
        "--crossings",
        action="store_true",
        help="worlds with side corridors across the chain, the paths spinning where they cross",
    )
    parser.add_argument(
        "--paired",
        type=_variant,
        metavar="JSON",
        help="instead of the ablation: the default against this variant (Config fields as a"
        " JSON object), paired per world: each measure's mean change and 2 SE",
    )
    parser.add_argument(
        "--out",
        type=Path,
        help="also write the table here (and, with"
        " --paired, the per-world scores beside it as .json)",
    )
    args = parser.parse_args()
    if args.brief and not args.entered:
        parser.error("--brief needs --entered")
    kind = WorldKind(
        spacing=args.spacing,
        turn=args.turn,
        entered=args.entered,
        brief=args.brief,
        revisit=args.revisit,
        crossings=args.crossings,
    )
    if args.paired is not None:
        started = time.perf_counter()
        table, per_world = paired(args.paired, args.seeds, **kind)
        text = f"The default against the variant, paired per world, {len(per_world)} worlds:\n\n"
        text += markdown(table, digits=4) + f"\n\n({time.perf_counter() - started:.0f} s)"
        print(text)
        if args.out:
            args.out.write_text(text + "\n")
            args.out.with_suffix(".json").write_text(json.dumps(per_world))
        return
    wrong = [i for i in args.rows or () if not 0 <= i < len(ABLATION)]
    if wrong:
        parser.error(f"--rows: no ablation row {wrong[0]} (rows 0-{len(ABLATION) - 1})")
    configs = [ABLATION[i] for i in args.rows] if args.rows else ABLATION
    started = time.perf_counter()
    table, places = protocol(configs, args.seeds, **kind)
    text = f"Random worlds, seeds {args.seeds[0]}-{args.seeds[-1]} ({len(args.seeds)})"
    if args.entered:
        text += ", paths entering rooms, taught as the Intel log"
        text += " (small rooms entered briefly)" if args.brief else ""
    if args.revisit:
        text += ", paths coming back to their start"
    if args.crossings:
        text += ", side corridors crossing the chain (the paths spinning there)"
    if args.spacing > 0:
        text += f", scans {args.spacing:g} m apart"
        text += f" or {args.turn:g} rad of turning" if args.turn > 0 else ""
    if args.spacing > 0 or args.entered:
        text += " (the seeds teaching two places or more)"
    text += ":\n\n"
    text += markdown(table) + "\n\nPer place, the default (means over the seeds):\n\n"
    text += markdown(places)
    if args.scenarios:
        text += "\n\nThe fixed scenarios (seed 0):\n\n" + markdown(scenarios_table(configs))
    text += f"\n\n({time.perf_counter() - started:.0f} s)"
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
