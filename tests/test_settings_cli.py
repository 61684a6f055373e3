"""Expert settings from the command line (`toolkit map` / `toolkit label` with --config FILE
and --set KEY=VALUE): the value reaches the run (config.json, model.json) and the poses; a
run's config.json read back maps the same; a bad key, value or file is one line, exit 1 and
no run. A fleet (`toolkit map` of several datasets) maps every dataset by the same settings,
here or on Dask workers, and its re-run keeps only the runs of these settings
(`run_is_current`, by what `recorded_settings` says config.json records)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tests.conftest import Cli
from toolkit.app.settings import apply, parse_sets
from toolkit.errors import ToolkitError


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 300-scan simulated corridor (seed 3) as a dataset with regions.csv."""
    from toolkit.app.simulation import write_simulation
    from toolkit.sim import simulate

    out = tmp_path_factory.mktemp("settings") / "corridor"
    write_simulation(simulate("corridor", seed=3, scans=300), out, "dataset")
    return out


@pytest.fixture(scope="module")
def blind(small: Path) -> Path:
    """`small` without odometry (as a log of an LMS-200 capture or a bag without it): the
    mapper's keyframe front end and the pair matcher (`MatchConfig`) map it."""
    out = small.parent / "blind"
    shutil.copytree(small, out)
    (out / "odometry.parquet").unlink()
    return out


@pytest.fixture
def fleet(small: Path, tmp_path: Path) -> Path:
    """Two datasets (copies of `small`) in a tree: a fleet for `toolkit map FLEET --out RUNS`."""
    for name in ("a", "b"):
        shutil.copytree(small, tmp_path / "fleet" / name)
    return tmp_path / "fleet"


def poses(run: Path) -> np.ndarray:
    return pd.read_parquet(run / "trajectory.parquet")[["x", "y", "theta"]].to_numpy()


def test_parse_sets_nests_keys_and_reads_json() -> None:
    sets = parse_sets(["slam.loop.radius=3", "slam.loops=false", "a=[1, 2]", "b=text", "c=null"])
    assert sets == {
        "slam": {"loop": {"radius": 3}, "loops": False},
        "a": [1, 2],
        "b": "text",
        "c": None,
    }
    with pytest.raises(ToolkitError, match="set apart"):
        parse_sets(["slam=1", "slam.loops=false"])


def test_apply_checks_types_and_converts() -> None:
    from toolkit.slam.pipeline import SlamConfig

    slam = apply(SlamConfig(), {"blind_turn": 0, "sigma_floor": [0.1, 0.2], "loop": {}}, "x")
    assert slam.blind_turn == 0.0 and isinstance(slam.blind_turn, float)
    assert slam.sigma_floor == (0.1, 0.2) and slam.loop == SlamConfig().loop
    for bad, needle in (
        ({"loops": 1}, "slam.loops: expected true or false"),
        ({"rounds": 1.5}, "slam.rounds: expected an integer"),
        ({"sigma_floor": [0.1]}, "slam.sigma_floor: expected a list of 2"),
        ({"loop": {"radiuss": 1}}, "did you mean slam.loop.radius?"),
    ):
        with pytest.raises(ToolkitError, match=needle.replace("?", r"\?")):
            apply(SlamConfig(), bad, "F", "slam.")


@pytest.mark.slow
def test_map_settings_reach_the_run(small: Path, tmp_path: Path, cli: Cli) -> None:
    code, _, err = cli("map", small, "--out", tmp_path / "default", "-q")
    assert code == 0, err
    # a run's config.json as --config: the same settings, the same poses to the bit
    code, _, err = cli(
        "map", small, "--out", tmp_path / "again", "--config", tmp_path / "default/config.json"
    )
    assert code == 0, err
    assert np.array_equal(poses(tmp_path / "default"), poses(tmp_path / "again"))
    partial = tmp_path / "partial.json"
    partial.write_text(json.dumps({"slam": {"blind_turn": 0}, "matcher": {"gate": 0.5}}))
    code, _, err = cli(
        "map", small, "--out", tmp_path / "set", "-q", "--config", partial,
        "--set", "slam.loop.radius=3", "--set", "matcher.gate=0.1",
    )  # fmt: skip
    assert code == 0, err
    config = json.loads((tmp_path / "set/config.json").read_text())
    assert config["slam"]["blind_turn"] == 0 and config["slam"]["loop"]["radius"] == 3
    # matcher.* with loops: the scan-to-map matcher's (slam.scan_map's); --set over --config
    assert config["matcher"]["gate"] == 0.1 == config["slam"]["scan_map"]["gate"]
    assert np.abs(poses(tmp_path / "set") - poses(tmp_path / "default")).max() > 0.01
    # without loops, matcher.* is the pair matcher's (MatchConfig)
    code, _, err = cli(
        "map", small, "--out", tmp_path / "pairs", "-q", "--no-loops", "--set", "iterations=1"
    )
    assert code == 1 and "unknown setting iterations" in err
    code, _, err = cli(
        "map", small, "--out", tmp_path / "pairs", "-q", "--no-loops",
        "--set", "matcher.iterations=1",
    )  # fmt: skip
    assert code == 0, err
    config = json.loads((tmp_path / "pairs/config.json").read_text())
    assert config["matcher"]["iterations"] == 1 and config["slam"] is None


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--set", "slam.nosuch=1"], "unknown setting slam.nosuch"),
        (["--set", "slam.blind_turn=abc"], 'slam.blind_turn: expected a number, not "abc"'),
        (["--set", "slam.loop=3"], "slam.loop: expected an object"),
        (["--set", "method=icp"], "unknown setting method"),
        (["--set", "slam.blind_turn"], "is not KEY=VALUE"),
        (["--no-loops", "--set", "slam.blind_turn=0"], "need loops"),
        (["--config", "missing.json"], "missing.json: no such file"),
        (["--config", "bad.json"], "bad.json:1: invalid JSON"),
        (["--config", "list.json"], "list.json: expected a JSON object"),
        (["--config", "typo.json"], "typo.json: unknown setting slam.blindturn"),
    ],
)
def test_map_bad_settings_are_one_line(
    small: Path, tmp_path: Path, cli: Cli, args: list[str], needle: str
) -> None:
    (tmp_path / "bad.json").write_text("{slam: 1}")
    (tmp_path / "list.json").write_text("[1, 2]")
    (tmp_path / "typo.json").write_text('{"slam": {"blindturn": 0}}')
    args = [str(tmp_path / a) if a.endswith(".json") else a for a in args]
    code, _, err = cli("map", small, "--out", tmp_path / "run", *args)
    assert code == 1
    assert len(err.strip().splitlines()) == 1 and needle in err, err
    assert "Traceback" not in err and "internal" not in err
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_label_settings_reach_the_model(small: Path, tmp_path: Path, cli: Cli) -> None:
    regions = small / "regions.csv"
    code, _, err = cli(
        "label", small, "--regions", regions, "--out", tmp_path / "a",
        "--set", "room_margin=0", "--set", 'glass_to=["window", "door"]',
    )  # fmt: skip
    assert code == 0, err
    saved = json.loads((tmp_path / "a/model.json").read_text())["config"]
    assert saved["room_margin"] == 0 and saved["glass_to"] == ["window", "door"]
    # a model.json as --config: its config section (as fitted: this log's scans lie too far
    # apart for the context, which the fit turned off), under the named options
    code, _, err = cli(
        "label", small, "--regions", regions, "--out", tmp_path / "b",
        "--config", tmp_path / "a/model.json", "--beam-term", "0.5",
    )  # fmt: skip
    assert code == 0, err
    again = json.loads((tmp_path / "b/model.json").read_text())["config"]
    assert again == {**saved, "beam_term": 0.5}


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--set", "room_margin=-1"], "room_margin: beside_reach, narrow_opening and room_margin"),
        (["--set", "roommargin=1"], "unknown setting roommargin (did you mean room_margin?)"),
        (["--set", "glass_to=[1]"], "glass_to: expected"),
        (["--set", "smoothing=sideways"], "smoothing: expected one of"),
        (["--config", "missing.json"], "missing.json: no such file"),
        (["--model", "model.json", "--set", "room_margin=0"], "a --model keeps its own"),
    ],
)
def test_label_bad_settings_are_one_line(
    small: Path, tmp_path: Path, cli: Cli, args: list[str], needle: str
) -> None:
    (tmp_path / "model.json").write_text("{}")
    args = [str(tmp_path / a) if a.endswith(".json") else a for a in args]
    code, _, err = cli(
        "label", small, "--regions", small / "regions.csv", "--out", tmp_path / "run", *args
    )
    assert code == 1
    assert len(err.strip().splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "run").exists()


#: settings that move the poses: the mapper's (the blind-step loosening off, as before
#: session 25) and the scan-to-map matcher's
OTHER = ["--set", "slam.blind_turn=0", "--set", "matcher.gate=0.3"]


@pytest.mark.slow
def test_fleet_maps_every_dataset_by_the_settings_and_reruns_other_ones(
    fleet: Path, tmp_path: Path, cli: Cli
) -> None:
    runs = tmp_path / "runs"

    def fleet_map(*args: object) -> str:
        code, out, err = cli("map", fleet, "--out", runs, *args)
        assert code == 0, err
        return out

    assert "2 written, 0 skipped" in fleet_map()
    default = poses(runs / "a")
    assert "0 written, 2 skipped" in fleet_map()
    # other settings: every run re-mapped, by them; the same again: current
    assert "2 written, 0 skipped" in fleet_map(*OTHER)
    assert not np.array_equal(poses(runs / "a"), default)
    for name in ("a", "b"):
        config = json.loads((runs / name / "config.json").read_text())
        assert config["slam"]["blind_turn"] == 0 and config["matcher"]["gate"] == 0.3
    assert "0 written, 2 skipped" in fleet_map(*OTHER)
    # the same settings from a run's config.json: current too
    assert "0 written, 2 skipped" in fleet_map("--config", runs / "a" / "config.json")
    # each fleet run is the single-dataset run of the same settings
    code, _, err = cli("map", fleet / "b", "--out", tmp_path / "one", "-q", *OTHER)
    assert code == 0, err
    assert np.array_equal(poses(runs / "b"), poses(tmp_path / "one"))
    # back to the defaults: re-mapped
    assert "2 written, 0 skipped" in fleet_map()
    # a run that records an older slam default (blind_turn 0, before session 25), or none of a
    # newer setting: re-mapped, the other run kept
    config_b = runs / "b" / "config.json"
    config = json.loads(config_b.read_text())
    config_b.write_text(json.dumps({**config, "slam": {**config["slam"], "blind_turn": 0.0}}))
    assert "1 written, 1 skipped" in fleet_map()
    config = json.loads(config_b.read_text())
    del config["slam"]["blind_min_turn"]
    config_b.write_text(json.dumps(config))
    assert "1 written, 1 skipped" in fleet_map()
    assert "0 written, 2 skipped" in fleet_map()


@pytest.mark.slow
@pytest.mark.xdist_group("dask")
def test_fleet_settings_travel_to_the_dask_workers(fleet: Path, tmp_path: Path, cli: Cli) -> None:
    """On a LocalCluster (one task per dataset) the runs are the in-process runs of the same
    settings, to the bit, and current for an in-process re-run of them."""
    runs = tmp_path / "runs"
    code, out, err = cli("map", fleet, "--out", runs, "--scheduler", "local:2", *OTHER)
    assert code == 0 and "2 written" in out, err
    code, _, err = cli("map", fleet / "a", "--out", tmp_path / "one", "-q", *OTHER)
    assert code == 0, err
    assert np.array_equal(poses(runs / "a"), poses(tmp_path / "one"))
    assert json.loads((runs / "a" / "config.json").read_text())["slam"]["blind_turn"] == 0
    code, out, err = cli("map", fleet, "--out", runs, *OTHER)
    assert code == 0 and "0 written, 2 skipped" in out, err


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--set", "slam.nosuch=1"], "unknown setting slam.nosuch"),
        (["--set", "slam.blind_turn=abc"], 'slam.blind_turn: expected a number, not "abc"'),
        (["--no-loops", "--set", "slam.blind_turn=0"], "need loops"),
        (["--config", "missing.json"], "missing.json: no such file"),
        (["--set", "matcher.max_correction=0.3"], "a setting of the pair matcher"),
    ],
)
def test_fleet_bad_settings_are_one_line_before_any_run(
    fleet: Path, tmp_path: Path, cli: Cli, args: list[str], needle: str
) -> None:
    args = [str(tmp_path / a) if a.endswith(".json") else a for a in args]
    code, _, err = cli("map", fleet, "--out", tmp_path / "runs", *args)
    assert code == 1
    assert len(err.strip().splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_recorded_settings_are_what_a_run_records(small: Path, tmp_path: Path) -> None:
    """`recorded_settings` predicts config.json's matcher and slam for each kind of run (the
    front end by the method, loops and odometry), and `run_is_current` takes the run as
    current for its own settings only."""
    from dataclasses import replace

    from toolkit.align.scan import MatchConfig
    from toolkit.app.fleet_map import run_is_current
    from toolkit.mapping import map_run, recorded_settings
    from toolkit.slam.pipeline import SlamConfig

    blind = tmp_path / "blind"  # the same scans without odometry
    shutil.copytree(small, blind)
    (blind / "odometry.parquet").unlink()
    pairs = MatchConfig(gate=0.3)
    slam = SlamConfig(blind_turn=0.0)
    cases = [
        (small, "gaussian", True, None, None),
        (small, "gaussian", True, pairs, replace(slam, front_end="keyframe")),
        (small, "gaussian", False, pairs, None),
        (small, "icp", True, pairs, slam),
        (small, "icp", False, None, None),
        (small, "odometry", False, None, None),
        (blind, "gaussian", True, pairs, slam),
    ]
    for i, (dataset, method, loops, config, slam_config) in enumerate(cases):
        run = tmp_path / f"run{i}"
        outputs = ("config.json", "metrics.json")
        map_run(dataset, run, method, 0.0, config, loops=loops, outputs=outputs,
                slam_config=slam_config)  # fmt: skip
        written = json.loads((run / "config.json").read_text())
        expected = recorded_settings(method, loops, config, slam_config, dataset == small)
        assert {k: written[k] for k in ("matcher", "slam")} == expected, (method, loops)
        assert run_is_current(run, dataset, method, 0.0, loops, config, slam_config)
        if method == "odometry":  # nothing matched: neither loops nor settings matter
            assert run_is_current(run, dataset, method, 0.0, not loops, pairs, slam)
            continue
        assert not run_is_current(run, dataset, method, 0.0, not loops, config, slam_config)
        # other pair-matcher settings matter unless the scan-to-map front end ran (loops,
        # gaussian, odometry); other mapper settings (scan-to-map's gate) with loops only
        other = replace(config or MatchConfig(), keyframe_distance=0.7)
        mapper = slam_config or SlamConfig()
        other_slam = replace(mapper, scan_map=replace(mapper.scan_map, gate=0.1))
        scan_to_map = written["matcher"].get("front_end") == "scan-to-map"
        assert scan_to_map == (method == "gaussian" and loops and mapper.front_end == "map"
                               and dataset == small)  # fmt: skip
        assert run_is_current(run, dataset, method, 0.0, loops, other, slam_config) == scan_to_map
        assert run_is_current(run, dataset, method, 0.0, loops, config, other_slam) == (not loops)
        assert not run_is_current(run, dataset, "icp-point", 0.0, loops, config, slam_config)


@pytest.mark.slow
def test_matcher_settings_reach_the_matcher_without_odometry(
    blind: Path, tmp_path: Path, cli: Cli
) -> None:
    """Without odometry the keyframe front end runs the pair matcher: matcher.* is its
    settings (before session 26 they went to the unused slam.scan_map, the poses unmoved)."""
    code, _, err = cli("map", blind, "--out", tmp_path / "default", "-q")
    assert code == 0, err
    code, _, err = cli(
        "map", blind, "--out", tmp_path / "gate", "-q", "--set", "matcher.gate=0.3",
        "--set", "matcher.max_correction=0.3",
    )  # fmt: skip
    assert code == 0, err
    config = json.loads((tmp_path / "gate/config.json").read_text())
    assert config["matcher"]["gate"] == 0.3 and config["matcher"]["max_correction"] == 0.3
    assert config["slam"]["front_end"] == "keyframe"
    default = json.loads((tmp_path / "default/config.json").read_text())
    assert config["slam"] == default["slam"]  # slam.scan_map untouched: it did not run
    assert np.abs(poses(tmp_path / "gate") - poses(tmp_path / "default")).max() > 0.01
    # the run's config.json as --config: the same poses to the bit
    code, _, err = cli(
        "map", blind, "--out", tmp_path / "again", "-q", "--config", tmp_path / "gate/config.json"
    )
    assert code == 0, err
    assert np.array_equal(poses(tmp_path / "gate"), poses(tmp_path / "again"))


@pytest.mark.parametrize(
    ("odometry", "args", "needle"),
    [
        (
            False,
            ["--set", "matcher.edge_grow=1"],
            "matcher.edge_grow: a setting of the scan-to-map",
        ),
        (True, ["--set", "matcher.max_correction=0.3"], "a setting of the pair matcher"),
        (True, ["--set", "slam.front_end=keyframe", "--set", "matcher.edge_grow=1"], "scan-to-map"),
        (True, ["--method", "icp", "--set", "matcher.gate=0.3"], "it runs ICP"),
        (True, ["--method", "odometry", "--set", "matcher.gate=0.3"], "matches no scans"),
        (False, ["--set", "matcher.gat=0.3"], "did you mean matcher.gate?"),
        (False, ["--config", "scan-to-map.json"], "a scan-to-map run's"),
    ],
)
def test_a_matcher_setting_no_matcher_uses_is_one_line(
    small: Path, blind: Path, tmp_path: Path, cli: Cli, odometry: bool, args: list[str],
    needle: str,
) -> None:  # fmt: skip
    """matcher.KEY that the matcher of this dataset does not have (the other matcher's, or
    none's), or a scan-to-map run's matcher on a log without odometry: exit 1, no run."""
    recorded = {"front_end": "scan-to-map", "gate": 0.3, "edge_grow": 1.0}
    (tmp_path / "scan-to-map.json").write_text(json.dumps({"matcher": recorded}))
    args = [str(tmp_path / a) if a.endswith(".json") else a for a in args]
    code, _, err = cli("map", small if odometry else blind, "--out", tmp_path / "run", *args)
    assert code == 1
    assert len(err.strip().splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_mixed_fleet_maps_each_dataset_by_its_own_matcher(
    small: Path, blind: Path, tmp_path: Path, cli: Cli
) -> None:
    """A fleet of a log with odometry (scan-to-map) and one without (the pair matcher):
    matcher.* reaches each dataset's own matcher, and a re-run redoes only the runs whose
    matcher's settings changed."""
    fleet, runs = tmp_path / "fleet", tmp_path / "runs"
    shutil.copytree(small, fleet / "odo")
    shutil.copytree(blind, fleet / "blind")

    def fleet_map(*args: object) -> str:
        code, out, err = cli("map", fleet, "--out", runs, *args)
        assert code == 0, err
        return out

    assert "2 written, 0 skipped" in fleet_map()
    default = {name: poses(runs / name) for name in ("odo", "blind")}
    # a key of the pair matcher alone: the log with odometry (scan-to-map) stays current
    assert "1 written, 1 skipped" in fleet_map("--set", "matcher.max_correction=0.3")
    assert np.array_equal(poses(runs / "odo"), default["odo"])
    both = ["--set", "matcher.gate=0.3", "--set", "matcher.edge_grow=1"]
    pair = ["--set", "matcher.max_correction=0.3"]
    assert "2 written, 0 skipped" in fleet_map(*both, *pair)
    odo = json.loads((runs / "odo/config.json").read_text())
    assert odo["matcher"]["front_end"] == "scan-to-map" and odo["matcher"]["edge_grow"] == 1
    assert odo["matcher"]["gate"] == 0.3 == odo["slam"]["scan_map"]["gate"]
    no_odo = json.loads((runs / "blind/config.json").read_text())
    assert no_odo["matcher"]["gate"] == 0.3 and no_odo["matcher"]["max_correction"] == 0.3
    assert no_odo["slam"]["scan_map"]["gate"] == 0.5  # the default: scan-to-map did not run
    for name in ("odo", "blind"):
        assert not np.array_equal(poses(runs / name), default[name]), name
    assert "0 written, 2 skipped" in fleet_map(*both, *pair)
    # each is the single-dataset run of its own matcher's settings, to the bit
    for name, args in (("odo", both), ("blind", [*both[:2], *pair])):
        code, _, err = cli("map", fleet / name, "--out", tmp_path / name, "-q", *args)
        assert code == 0, err
        assert np.array_equal(poses(runs / name), poses(tmp_path / name)), name
