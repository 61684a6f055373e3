"""Expert settings from the command line (`toolkit map` / `toolkit label` with --config FILE
and --set KEY=VALUE): the value reaches the run (config.json, model.json) and the poses; a
run's config.json read back maps the same; a bad key, value or file is one line, exit 1 and
no run."""

from __future__ import annotations

import json
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
