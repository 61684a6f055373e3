"""The random worlds (`toolkit simulate random`): every world holds every place kind, the path
stays inside the building, a seed gives one world and each route its own path through it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tests.conftest import Cli
from toolkit.sim import simulate
from toolkit.sim.procedural import PLACES, random_world
from toolkit.sim.truth import runs


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_every_world_holds_every_place_and_regions_as_a_user_picks_them(seed: int) -> None:
    sim = simulate("random", seed=seed)
    assert set(sim.labels) == set(PLACES)
    regions = sim.regions
    assert set(regions.feature) == set(PLACES)
    t = sim.dataset.t
    for place, spans in regions.groupby("feature"):
        assert 1 <= len(spans) <= 2  # one or two spans, ten scans in all
        inside = np.zeros(len(t), dtype=bool)
        for row in spans.itertuples():
            inside |= (t >= row.start) & (t <= row.end)
        assert inside.sum() == 10
        assert set(sim.labels[inside]) == {place}  # every training scan is of its place
    # the robot stays inside the building: nothing closer than the corridor's clutter allows
    assert np.nanmin(sim.dataset.ranges) > 0.1
    # each open door is a short place: the robot passes it in one run of a few scans
    door_runs = [last - first + 1 for label, first, last in runs(sim.labels) if label == "door"]
    assert len(door_runs) >= 2 and max(door_runs) < 40


def test_seed_draws_the_world_and_route_the_path() -> None:
    a, again, other = random_world(5), random_world(5), random_world(6)
    assert np.array_equal(a.world.segments, again.world.segments)
    assert a.world.segments.shape != other.world.segments.shape or not np.allclose(
        a.world.segments, other.world.segments
    )
    back = random_world(5, route=1)
    assert np.array_equal(back.world.segments, a.world.segments)  # the same building
    # the other way round: it starts where the first route ends
    assert np.hypot(*(back.waypoints[0] - a.waypoints[-1])) < 4.0
    first, second = simulate("random", seed=5), simulate("random", seed=5, route=1)
    # the same place kinds on both runs, labelled where the robot is
    assert set(first.labels) == set(second.labels) == set(PLACES)


def test_corridor_widths_vary_between_worlds() -> None:
    widths = []
    for seed in range(12):
        corner = next(z for z in random_world(seed).zones if z.label == "corner")
        widths.append(corner.x1 - corner.x0 - 0.6)  # the crossing: the corridor's width
    assert min(widths) >= 1.6 - 1e-9 and max(widths) <= 4.0 + 1e-9
    assert max(widths) - min(widths) > 1.0


def test_cli_simulates_a_random_world_on_another_route(tmp_path: Path, cli: Cli) -> None:
    out = tmp_path / "random"
    code, stdout, _ = cli(
        "simulate", "random", "--seed", "3", "-p", "route=1", "--out", str(out), "-f", "dataset"
    )
    assert code == 0, stdout
    truth = pd.read_parquet(out / "truth.parquet")
    assert set(truth.label) == set(PLACES)
    code, _, err = cli(
        "simulate", "corridor", "-p", "route=1", "--out", str(tmp_path / "c"), "-f", "dataset"
    )
    assert code == 1 and "route" in err


def test_worlds_and_paths_without_entered_are_as_before() -> None:
    """`entered` is off by default: seed 5's paths as before the option (session 25)."""
    first, back = random_world(5), random_world(5, route=1)
    assert (first.scans, back.scans, len(first.zones)) == (1573, 1788, 9)
    assert np.allclose(first.waypoints[:3], [[1.0, -0.246144], [32.143306, -0.246144], [32.143306, -17.732656]], atol=1e-6)  # fmt: skip
    assert np.allclose(back.waypoints[-1], [1.0, 0.171801], atol=1e-6)
    assert "room" not in {z.label for z in first.zones}


@pytest.mark.parametrize("seed", [0, 3])
def test_entered_paths_enter_rooms_labelled_room(seed: int) -> None:
    """With `entered` the building is the same, the path turns at two doors or more, drives
    into the room (its laser positions labelled "room", from the doorway on), turns there and
    comes back out; the other route enters the same rooms."""
    plain, entered = random_world(seed), random_world(seed, entered=True)
    assert np.array_equal(plain.world.segments, entered.world.segments)
    rooms = [z for z in entered.zones if z.label == "room"]
    assert len(rooms) == sum(z.label == "door" for z in entered.zones)  # a zone per open door
    sim = simulate("random", seed=seed, entered=True)
    assert sim.params["entered"] is True and "entered" not in simulate("random", seed=seed).params
    visits = [(first, last) for label, first, last in runs(sim.labels) if label == "room"]
    assert len(visits) >= 2
    for first, last in visits:
        assert sim.labels[first - 1] == "door" and sim.labels[last + 1] == "door"  # the doorway
        assert last - first > 50  # in, a look left and right, out: many scans
    gt = sim.dataset.groundtruth
    assert gt is not None
    # inside, the robot turns: more than a full turn per visit
    turned = [np.abs(np.diff(np.unwrap(gt.theta.to_numpy()[a : b + 1]))).sum() for a, b in visits]
    assert min(turned) > 2 * np.pi
    assert np.nanmin(sim.dataset.ranges) > 0.1  # nothing hit
    back = simulate("random", seed=seed, route=1, entered=True)
    assert sum(label == "room" for label, _, _ in runs(back.labels)) == len(visits)
    assert set(sim.labels) == set(PLACES) | {"room"}


def test_entered_worlds_without_brief_are_as_before() -> None:
    """`brief` is off by default: seed 5's entered paths as before the option (session 26)."""
    for route, scans, total in ((0, 2015, [891.32154913, -349.23877884]), (1, 2277, [892.99333079, -345.0593247])):  # fmt: skip
        world = random_world(5, route, entered=True)
        assert (world.scans, len(world.zones), len(world.waypoints)) == (scans, 11, 18)
        assert np.allclose(world.waypoints.sum(axis=0), total, atol=1e-6)


@pytest.mark.parametrize("seed", [0, 1])
def test_brief_visits_enter_small_rooms_for_a_few_scans(seed: int) -> None:
    """With `brief` two rooms are large and entered fully, every other open door leads to a
    small room entered briefly: thinned as the Intel log (1 m or 0.5 rad), 6-10 scans turning
    3-4 rad, as the Intel rooms' short visits; the full visits longer than ten scans (taught)."""
    from toolkit.features.evaluate import thinned

    world = random_world(seed, entered=True, brief=True)
    sizes = sorted(
        min(z.x1 - z.x0, z.y1 - z.y0) for z in world.zones if z.label == "room"
    )  # the smaller side of each room
    assert len(sizes) >= 4 and sum(s >= 4.5 for s in sizes) == 2
    assert all(2.2 <= s <= 3.2 for s in sizes[:-2])
    sim = thinned(simulate("random", seed=seed, entered=True, brief=True), 1.0, 0.5)
    assert sim.params["brief"] is True and "brief" not in simulate("random", seed=seed).params
    gt = sim.dataset.groundtruth
    assert gt is not None
    heading = np.unwrap(gt.theta.to_numpy())
    visits = [(a, b) for label, a, b in runs(sim.labels) if label == "room"]
    scans = np.array([b - a + 1 for a, b in visits])
    turned = np.array([np.abs(np.diff(heading[a : b + 1])).sum() for a, b in visits])
    short = scans <= 10
    assert short.sum() == len(sizes) - 2 and (~short).sum() == 2
    assert np.all((scans[short] >= 6) & (turned[short] > 2.8) & (turned[short] < 4.0))
    assert np.all(turned[~short] > 2 * np.pi)
    assert np.nanmin(sim.dataset.ranges) > 0.1  # nothing hit


def test_brief_needs_entered(cli: Cli, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="entered"):
        random_world(0, brief=True)
    code, _, err = cli(
        "simulate", "random", "-p", "brief=true", "--out", str(tmp_path / "r"), "-f", "dataset"
    )
    assert code == 1 and "entered" in err
    done = subprocess.run(
        [sys.executable, "-m", "toolkit.features.evaluate", "--seeds", "0", "--brief"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2 and "--brief needs --entered" in done.stderr


@pytest.mark.parametrize("kw", [{}, {"entered": True}, {"entered": True, "brief": True}])
def test_revisit_adds_a_way_back_and_changes_nothing_else(kw: dict[str, bool]) -> None:
    """`revisit` is off by default; on, the world, its zones and regions' parts and the way out
    are the same to the bit (the way back draws from its own generator), the scans about
    double, and the way back ends where the path started."""
    for seed, route in ((0, 0), (3, 1), (2001, 0)):
        plain = random_world(seed, route, **kw)
        assert np.array_equal(
            random_world(seed, route, revisit=False, **kw).waypoints, plain.waypoints
        )
        both = random_world(seed, route, revisit=True, **kw)
        assert np.array_equal(both.world.segments, plain.world.segments)
        assert both.zones == plain.zones and both.region_parts == plain.region_parts
        assert np.array_equal(both.waypoints[: len(plain.waypoints)], plain.waypoints)
        assert 1.7 < both.scans / plain.scans < 2.3
        first, end = plain.waypoints[0], both.waypoints[-1]
        assert np.hypot(*(first - end)) < 1.6  # the offsets differ by 0.4 width at most
        assert not np.any(np.all(np.diff(both.waypoints, axis=0) == 0, axis=1))  # no empty leg


@pytest.mark.parametrize(("seed", "rooms"), [(0, (4, 4)), (3, (3, 2))])
def test_the_way_back_sees_the_way_out_again_with_the_same_labels(
    seed: int, rooms: tuple[int, int]
) -> None:
    """With `revisit` nearly every corridor position of the way out has a way-back scan within
    1 m, labelled the same (labels are by position); the robot turns on the spot at the far
    end (half a turn); the regions are on the way out; the way back enters rooms of its own
    choice (brief: every room on the way out, on seed 3 not all of them on the way back)."""
    sim = simulate("random", seed=seed, entered=True, brief=True, revisit=True)
    assert sim.params["revisit"] is True
    assert "revisit" not in simulate("random", seed=seed, entered=True).params
    out = random_world(seed, entered=True, brief=True)
    gt = sim.dataset.groundtruth
    assert gt is not None
    xy, heading = gt[["x", "y"]].to_numpy(), np.unwrap(gt.theta.to_numpy())
    far = int(np.argmin(np.hypot(*(xy - out.waypoints[-1]).T)))  # the way out's end
    assert abs(far - out.scans) < 0.02 * out.scans
    way_out, way_back = np.arange(far), np.arange(far, len(xy))
    corridor = way_out[sim.labels[way_out] == "corridor"]
    gap = np.hypot(*(xy[corridor, None] - xy[None, way_back]).transpose(2, 0, 1))
    near, nearest = gap.min(axis=1) < 1.0, way_back[gap.argmin(axis=1)]
    assert near.mean() > 0.95
    assert np.mean(sim.labels[nearest[near]] == "corridor") > 0.9
    step = np.hypot(*np.diff(xy[far - 1 : far + 80], axis=0).T)
    turn = np.diff(heading[far - 1 : far + 80])
    assert abs(abs(turn.sum()) - np.pi) < 0.05  # back the way it came
    assert 2.8 < np.abs(turn[step < 0.02]).sum() < np.pi + 0.05  # on the spot: two quarters
    assert sim.regions.end.max() < sim.dataset.t[far]
    visits = np.array([a for label, a, _ in runs(sim.labels) if label == "room"])
    assert ((visits < far).sum(), (visits >= far).sum()) == rooms


def test_revisit_on_the_command_line_and_in_the_protocol(tmp_path: Path, cli: Cli) -> None:
    """`-p revisit=true` (random worlds only) and `evaluate --revisit`: every run comes back;
    run a's regions (taught as the Intel log) stay on the way out."""
    from toolkit.features.evaluate import worlds

    out = tmp_path / "random"
    code, stdout, _ = cli(
        "simulate",
        "random",
        "--seed",
        "1",
        "-p",
        "revisit=true",
        "--out",
        str(out),
        "-f",
        "dataset",
    )
    assert code == 0, stdout
    truth = pd.read_parquet(out / "truth.parquet")
    assert len(truth) == random_world(1, revisit=True).scans
    code, _, err = cli(
        "simulate", "corridor", "-p", "revisit=true", "--out", str(tmp_path / "c"), "-f", "dataset"
    )
    assert code == 1 and "revisit" in err
    plain, runs_back = worlds(2, 1.0, 0.5, True, True), worlds(2, 1.0, 0.5, True, True, True)
    for key in "abc":
        assert runs_back[key].params["revisit"] is True
        assert 1.4 < runs_back[key].dataset.n_scans / plain[key].dataset.n_scans < 2.3
    a = runs_back["a"]
    end = random_world(2, entered=True, brief=True).waypoints[-1]  # the way out's end
    gt = a.dataset.groundtruth
    assert gt is not None
    far = int(np.argmin(np.hypot(*(gt[["x", "y"]].to_numpy() - end).T)))
    assert set(a.regions.feature) == {"corridor", "room"}
    assert a.regions.end.max() < a.dataset.t[far]
