"""A door call only where the laser has an opening beside it (`Config.beside_reach`,
classify.beside_only): the opening's distance along the path on a ray-cast corridor, and
the door's false calls past its zone on a random world."""

from __future__ import annotations

import typing
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tests.features import world
from tests.features.world import LASER, cast, drive
from toolkit.errors import ToolkitError
from toolkit.features import Config, fit
from toolkit.features.classify import beside_only, classify, glass_room, openings
from toolkit.features.model import FeatureModel
from toolkit.features.regions import spans_from_frame, training_indices
from toolkit.sim import simulate


def test_opening_distance_is_the_path_to_the_room_beside_the_corridor() -> None:
    """Along the test world's 2 m corridor the room above opens at x 12: the path to the
    first scan whose square beams see into it is 12 m less the laser's x (less the 0.05 m
    ahead at which the beam at 87 degrees crosses the wall line), within a step of 0.1 m;
    in the room's stretch it is 0; the pillar at x 5 (0.2 m out of the wall) is no opening.
    A laser with no beam square to the path measures nothing."""
    x = np.arange(1.0, 38.0, 0.1)
    poses = np.c_[x, np.zeros_like(x), np.zeros_like(x)]  # the centre line
    found = openings(cast(poses), LASER, poses)
    assert found is not None
    distance = found[0]
    before = (x > 6.0) & (x < 11.9)
    assert np.all(np.abs(distance[before] - (11.95 - x[before])) <= 0.1)
    assert np.all(distance[(x > 12.1) & (x < 15.9)] == 0.0)
    assert np.all(distance[x < 6.0] > 5.0)
    narrow = replace(LASER, beams=120, angle_min=float(LASER.angles[30]))
    assert openings(cast(poses, narrow), narrow, poses) is None


def test_a_doors_opening_is_short_and_a_halls_long(monkeypatch: pytest.MonkeyPatch) -> None:
    """A 2 m corridor (x 0..30) with a 0.9 m door (x 9.55..10.45) into a 3 m deep room on the
    left and a hall 10 m long (x 16..26) 4 m deep on the right: the run of scans whose square
    beams see through the door is 0.9 m long less a step or two, the hall's 10 m less one;
    each scan gets its nearest opening's length."""
    w = [
        (0, 1, 9.55, 1), (9.55, 1, 9.55, 4), (9.55, 4, 10.45, 4), (10.45, 4, 10.45, 1),
        (10.45, 1, 30, 1), (0, -1, 16, -1), (16, -1, 16, -5), (16, -5, 26, -5),
        (26, -5, 26, -1), (26, -1, 30, -1), (0, -1, 0, 1), (30, -1, 30, 1),
    ]  # fmt: skip
    monkeypatch.setattr(world, "walls", lambda: np.array(w, dtype=np.float64))
    x = np.arange(1.0, 29.0, 0.05)
    poses = np.c_[x, np.zeros_like(x), np.zeros_like(x)]
    found = openings(cast(poses), LASER, poses)
    assert found is not None
    distance, length, along = found
    assert np.allclose(along, x - 1.0)
    assert 0.75 <= length[np.argmin(np.abs(x - 10.0))] <= 0.9
    assert 9.85 <= length[np.argmin(np.abs(x - 21.0))] <= 10.0
    assert np.all(length[x < 13.0] < 1.0) and np.all(length[(x > 14.0) & (x < 28.0)] > 9.0)
    assert np.all(distance[(x > 9.6) & (x < 10.35)] == 0.0)


#: session 24's first default: the rules keyed to the places' names
NAMED: dict[str, typing.Any] = {"beside_places": ("door", "hall"), "narrow_places": ("door",)}


def test_door_calls_past_the_opening_go_to_the_next_place() -> None:
    """Random world 7 (development), taught on run a, labelling run b: with the rules keyed
    to the names door and hall, the door and hall calls more than 0.5 m of path from an
    opening beside the laser, and the door calls whose nearest opening is longer than 2 m,
    go to their next place; the door's precision rises (0.846 -> 0.930), no true door scan
    is lost, every other scan keeps its label; streaming, nothing changes."""
    model, ranges, their, truth = _taught(7, {}, Config(**NAMED))
    after = classify(model, ranges, their)
    model.config = Config(beside_reach=0.0, narrow_opening=0.0)
    before = classify(model, ranges, their)
    found = openings(ranges, model.laser, their)
    assert found is not None
    distance, length, _ = found
    changed = before.label != after.label
    assert changed.any()
    far, door = distance[changed] > 0.5, before.label[changed] == "door"
    assert np.all((far & np.isin(before.label[changed], ["door", "hall"])) | (door & ~far))
    assert np.all(length[changed][~far] > 2.0)
    assert not np.any((truth == "door") & (before.label == "door") & (after.label != "door"))

    def precision(label: np.ndarray) -> float:
        return float(np.mean(truth[label == "door"] == "door"))

    assert precision(after.label) > precision(before.label) + 0.05
    np.testing.assert_allclose(after.prob.sum(axis=1), 1.0)
    # streaming (the forward filter): the rules look ahead, so they are left out
    model.config = Config(smoothing="forward")
    streamed = classify(model, ranges, their)
    model.config = Config(smoothing="forward", beside_reach=0.0, narrow_opening=0.0)
    assert np.array_equal(streamed.prob, classify(model, ranges, their).prob)


def test_beside_only_leaves_sparse_logs_and_logs_without_poses_alone() -> None:
    """Where the scans lie more than half the reach apart (here 1 m) or there are no poses,
    the posteriors are returned as they are."""
    _, poses, _ = drive(step=1.0)
    ranges = cast(poses)
    prob = np.tile([0.7, 0.3], (len(poses), 1))

    fields = {"config": Config(), "classes": ["door", "corridor"], "laser": LASER}
    model = typing.cast(FeatureModel, SimpleNamespace(**fields))  # the fields beside_only reads
    assert beside_only(prob, model, ranges, poses) is prob
    assert beside_only(prob, model, ranges, None) is prob


def _taught(
    seed: int, rename: dict[str, str], config: Config | None = None
) -> tuple[FeatureModel, np.ndarray, np.ndarray, np.ndarray]:
    """Random world `seed`'s model taught on run a with its places renamed (`config`, default
    Config(), its settings keyed to names renamed alike); run b's scans, poses and truth."""
    train, other = simulate("random", seed=seed), simulate("random", seed=seed, route=1)
    ds, ob = train.dataset, other.dataset
    assert ds.groundtruth is not None and ob.groundtruth is not None
    regions = train.regions.assign(feature=train.regions["feature"].replace(rename))
    spans = spans_from_frame(regions, ds.t)
    poses = ds.groundtruth[["x", "y", "theta"]].to_numpy()
    cfg = config or Config()
    named: dict[str, typing.Any] = {
        k: tuple(rename.get(p, p) for p in getattr(cfg, k))
        for k in ("resemble_places", "ends_of", "starts_of")
    }
    cfg = replace(cfg, **named)
    model = fit(ds.ranges, ds.laser, training_indices(spans), cfg, spans, poses)
    their = ob.groundtruth[["x", "y", "theta"]].to_numpy()
    return model, ob.ranges, their, np.asarray(other.labels).astype(str)


def test_the_rules_places_are_learnt_from_the_taught_scans_not_their_names(
    tmp_path: Path,
) -> None:
    """Random world 7 (development), by default: the taught door, hall and corner lie at an
    opening beside the laser (the reach rule), the door's opening is short with a room
    behind it (the length rule), the corridor and the window (glass: no return) get
    neither; the model saves what it learnt. The door renamed "doorway" and the hall
    "lobby" (and so in the settings keyed to names: `resemble_places`, `ends_of`,
    `starts_of`) learn the same and label run b alike, name for name; the names as an expert
    override give session 24's first posteriors but where the corner is ruled out."""
    model, ranges, poses, _ = _taught(7, {})
    assert set(model.opening_places["beside"]) == {"door", "hall", "corner"}
    assert model.opening_places["narrow"] == ("door",)
    loaded = FeatureModel.load(model.save(tmp_path / "model.json"))
    assert loaded.opening_places == model.opening_places
    learnt = classify(model, ranges, poses)
    renamed, _, _, _ = _taught(7, {"door": "doorway", "hall": "lobby"})
    assert set(renamed.opening_places["beside"]) == {"doorway", "lobby", "corner"}
    assert renamed.opening_places["narrow"] == ("doorway",)
    other = classify(renamed, ranges, poses)
    back = np.array([{"doorway": "door", "lobby": "hall"}.get(x, x) for x in other.label])
    assert np.array_equal(back, learnt.label)
    model.config = Config(**NAMED)
    named = classify(model, ranges, poses)
    found = openings(ranges, model.laser, poses)
    assert found is not None
    rows = np.any(named.prob != learnt.prob, axis=1)  # the corner ruled out far from openings
    corner = model.classes.index("corner")
    assert rows.any() and np.all(found[0][rows] > 0.5) and np.all(learnt.prob[rows, corner] == 0)
    changed = named.label != learnt.label
    assert np.all(named.label[changed] == "corner")
    # named after the user's words, the names-keyed rules do nothing for them
    renamed.config = replace(renamed.config, **NAMED)
    assert not np.array_equal(classify(renamed, ranges, poses).label, other.label)


def test_a_window_call_that_sees_a_room_beside_goes_to_the_door() -> None:
    """Random world 3 (development; a door across the path from a window), taught on run a,
    labelling run b: by default the glass and room places are learnt from the taught scans
    (the window: no return at a square beam, never a room; the door: a short opening with a
    room behind it) and the 13 scans called window whose square beams see a room 1-5 m past
    a side's usual wall are called door, every one of them a door scan in truth, exactly as
    with `glass_to` ("window", "door") named; every other scan keeps its label and
    posterior; streaming, nothing changes; a `glass_to` that is not a pair is refused."""
    model, ranges, their, truth = _taught(3, {})
    assert model.config.glass_to is None
    assert model.opening_places["glass"] == ("window",)
    assert model.opening_places["room"] == ("door",)
    model.config = replace(model.config, room_margin=0.0)  # this rule alone
    new = classify(model, ranges, their)
    model.config = replace(model.config, glass_to=("window", "door"))
    assert np.array_equal(classify(model, ranges, their).prob, new.prob)
    model.config = replace(model.config, glass_to=())
    base = classify(model, ranges, their)
    model.config = replace(model.config, glass_to=None)
    moved = base.label != new.label
    assert moved.sum() == 13
    assert set(base.label[moved]) == {"window"} and set(new.label[moved]) == {"door"}
    assert set(truth[moved]) == {"door"}
    assert np.array_equal(base.prob[~moved], new.prob[~moved])
    assert np.array_equal(glass_room(base.prob, model, ranges), new.prob)
    np.testing.assert_allclose(new.prob.sum(axis=1), 1.0)
    # streaming (the forward filter): the usual wall is the whole log's, so it is left out
    model.config = replace(model.config, smoothing="forward")
    streamed = classify(model, ranges, their)
    model.config = replace(model.config, glass_to=())
    assert np.array_equal(streamed.prob, classify(model, ranges, their).prob)
    with pytest.raises(ToolkitError):
        Config(glass_to=("window",))


def test_the_glass_and_room_places_are_learnt_whatever_their_names() -> None:
    """World 3 with the window taught as "glazing" and the door as "doorway": the same
    places are learnt and run b is labelled alike, name for name; the pair named after
    session 24's words ("window", "door") does nothing for them (the 13 window calls the
    room goes to and the 5 corridor calls past the door's opening stay)."""
    model, ranges, their, _ = _taught(3, {})
    original = classify(model, ranges, their)
    rename = {"window": "glazing", "door": "doorway"}
    renamed, _, _, _ = _taught(3, rename)
    assert renamed.opening_places["glass"] == ("glazing",)
    assert renamed.opening_places["room"] == ("doorway",)
    labels = classify(renamed, ranges, their)
    back = {v: k for k, v in rename.items()}
    assert np.array_equal(np.array([back.get(x, x) for x in labels.label]), original.label)
    renamed.config = replace(renamed.config, glass_to=("window", "door"))
    keyed = classify(renamed, ranges, their)
    assert (keyed.label != labels.label).sum() == 13 + 5


def test_a_corridor_call_by_a_found_door_goes_to_the_door_with_room_margin() -> None:
    """Random world 3 (development), taught on run a, labelling run b: with `room_margin`
    0.4 (the default) against 0 (off): the 5 scans called corridor, with the door the
    runner-up, within 0.4 m of path of a door call that sees a room beside the laser are called door, every
    one a door scan in truth (the door zone past its opening); every other scan keeps its
    posterior; streaming, nothing changes; a negative margin is refused."""
    model, ranges, their, truth = _taught(3, {})
    assert model.config.room_margin == 0.4
    new = classify(model, ranges, their)
    model.config = replace(model.config, room_margin=0.0)
    base = classify(model, ranges, their)
    moved = base.label != new.label
    assert moved.sum() == 5
    assert set(base.label[moved]) == {"corridor"} and set(new.label[moved]) == {"door"}
    assert set(truth[moved]) == {"door"}
    assert np.array_equal(base.prob[~moved], new.prob[~moved])
    np.testing.assert_allclose(new.prob.sum(axis=1), 1.0)
    model.config = replace(model.config, smoothing="forward")
    streamed = classify(model, ranges, their)
    model.config = replace(model.config, room_margin=0.0)
    assert np.array_equal(streamed.prob, classify(model, ranges, their).prob)
    with pytest.raises(ToolkitError):
        Config(room_margin=-0.1)
