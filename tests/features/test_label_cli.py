"""`toolkit label` end to end on simulated logs written by `toolkit simulate`: the files of a
run, applying a saved model to another log, and one-line errors with exit status 1."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from tests.conftest import Cli
from toolkit.features import FeatureModel
from toolkit.sim import Simulation

pytestmark = pytest.mark.slow  # `toolkit label` end to end, five runs of ~5-15 s


@pytest.fixture(scope="module")
def sim_dirs(
    tmp_path_factory: pytest.TempPathFactory, corridor_sim: Simulation
) -> tuple[Path, Path]:
    """Two simulated corridor logs (seeds 0 and 1) as `toolkit simulate --format dataset`
    writes them: a dataset directory with regions.csv and truth.parquet."""
    from toolkit.app.simulation import write_simulation
    from toolkit.sim import simulate

    root = tmp_path_factory.mktemp("sim")
    dirs = []
    for seed in (0, 1):
        out = root / f"corridor-{seed}"
        sim = corridor_sim if seed == 0 else simulate("corridor", seed=seed)
        write_simulation(sim, out, "dataset")
        dirs.append(out)
    return dirs[0], dirs[1]


def learn(cli: Cli, data: Path, run: Path, *options: object) -> dict[str, Any]:
    """`toolkit label` with the log's own regions.csv; its labels-metrics.json."""
    code, _, err = cli("label", data, "--regions", data / "regions.csv", "--out", run, *options)
    assert code == 0, err
    return dict(json.loads((run / "labels-metrics.json").read_text()))


def test_label_writes_the_run(sim_dirs: tuple[Path, Path], tmp_path: Path, cli: Cli) -> None:
    data, _ = sim_dirs
    run = tmp_path / "run"
    code, out, err = cli("label", data, "--regions", data / "regions.csv", "--out", run)
    assert code == 0, err
    assert "balanced accuracy" in out  # truth.parquet beside the scans is used for scores
    labels = pd.read_parquet(run / "labels.parquet")
    regions = pd.read_csv(data / "regions.csv")
    features = list(dict.fromkeys(regions["feature"]))
    assert list(labels.columns) == ["t", *[f"p_{f}" for f in features], "p_none", "label"]
    probs = labels[[c for c in labels.columns if c.startswith("p_")]].to_numpy()
    assert np.allclose(probs.sum(axis=1), 1.0)
    truth = pd.read_parquet(data / "truth.parquet")
    assert np.array_equal(labels["t"].to_numpy(), truth["t"].to_numpy())
    model = json.loads((run / "model.json").read_text())
    assert [f["name"] for f in model["features"]] == regions["feature"].tolist()  # a row per span
    assert len(model["features"][0]["mean"]) == 181 and model["laser"]["beams"] == 181
    assert [s["feature"] for s in model["training_spans"]] == regions["feature"].tolist()
    assert all(s["scans"] == 5 for s in model["training_spans"])  # two halves of 5 scans
    metrics = json.loads((run / "labels-metrics.json").read_text())
    assert metrics["poses"] == "groundtruth"
    # the paper's model is scored alongside: the toolkit's must do better on the same log
    paper = learn(cli, data, tmp_path / "paper", "--paper")
    assert metrics["truth"]["balanced_accuracy"] > paper["truth"]["balanced_accuracy"] + 0.2
    # (calibrated here only with --none-model surroundings: the default's "none" gate does not
    # call the untaught plain corridor "none", docs/places.md; see the test below)
    assert (run / "membership.png").stat().st_size > 10_000
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(run / "labels-cloud.ply"))
    assert len(cloud.points) == metrics["cloud_points"] > 100_000
    assert np.allclose(np.asarray(cloud.points)[:, 2], 0.30)  # the laser's mounting height
    # a second run into the same directory needs --force
    code, _, err = cli("label", data, "--regions", data / "regions.csv", "--out", run)
    assert code == 1 and "--force" in err and len(err.strip().splitlines()) == 1


def test_surroundings_find_the_plain_corridor_calibrated(
    sim_dirs: tuple[Path, Path], tmp_path: Path, cli: Cli
) -> None:
    """--none-model surroundings: the plain corridor is "none" (not a door or a window whose
    ordinary beams it shares), and the probabilities are calibrated (the issue's ECE target)."""
    data, _ = sim_dirs
    world, around = (
        learn(cli, data, tmp_path / m, "--none-model", m)["truth"]
        for m in ("world", "surroundings")
    )
    assert around["recall"]["none"] > 0.9 > 0.5 > world["recall"]["none"]
    assert around["balanced_accuracy"] > world["balanced_accuracy"] + 0.03
    assert around["ece"] <= 0.05 < world["ece"]
    model = json.loads((tmp_path / "surroundings" / "model.json").read_text())
    assert model["config"]["none_model"] == "surroundings" and model["config"]["strict_returns"]
    assert all("none_offset" in f for f in model["features"])
    code, _, err = cli("label", data, "--regions", data / "regions.csv", "--out",
                       tmp_path / "bad", "--none-model", "nothing")  # fmt: skip
    assert code == 1 and "--none-model 'nothing'" in err


def test_lateral_beams_place_the_robot_by_what_is_beside_it(
    sim_dirs: tuple[Path, Path], tmp_path: Path, cli: Cli
) -> None:
    """Beams weighted by |sin(bearing)|^K, so that a doorway or a window ahead no longer
    claims the corridor before the robot is beside it. With --none-model surroundings the
    training spans choose K by leave-one-span-out (2 here): better than all beams alike, and
    within the issue's targets (balanced accuracy 0.95, ECE 0.05)."""
    data, _ = sim_dirs
    alike, auto, two = (
        learn(cli, data, tmp_path / name, "--none-model", "surroundings", *extra)["truth"]
        for name, extra in (("alike", ("--lateral", 0)), ("auto", ()), ("two", ("--lateral", 2)))
    )
    assert auto == two
    assert auto["balanced_accuracy"] > alike["balanced_accuracy"] + 0.01
    assert auto["recall"]["window_a"] > alike["recall"]["window_a"]
    assert auto["balanced_accuracy"] >= 0.95 and auto["ece"] <= 0.05
    model = json.loads((tmp_path / "auto" / "model.json").read_text())
    assert model["config"]["lateral_weight"] == 2.0  # saved resolved: --model reuses it
    scores = model["fit_report"]["lateral_scores"]
    assert list(scores) == ["0", "1", "2"] and max(scores, key=scores.get) == "2"
    for bad in ("-1", "nine"):
        code, _, err = cli("label", data, "--regions", data / "regions.csv", "--out",
                           tmp_path / "bad", "--lateral", bad)  # fmt: skip
        assert code == 1 and f"--lateral {bad}" in err and not (tmp_path / "bad").exists()


def test_saved_model_applies_to_another_log(
    sim_dirs: tuple[Path, Path], tmp_path: Path, cli: Cli
) -> None:
    first, second = sim_dirs
    learnt = learn(cli, first, tmp_path / "a")
    code, _, err = cli(
        "label",
        second,
        "--model",
        tmp_path / "a" / "model.json",
        "--out",
        tmp_path / "b",
    )
    assert code == 0, err
    applied = json.loads((tmp_path / "b" / "labels-metrics.json").read_text())
    assert applied["model"].endswith("model.json")
    # a model from one log finds the places of another log of the same sensor about as well
    assert applied["truth"]["balanced_accuracy"] > learnt["truth"]["balanced_accuracy"] - 0.1
    model = FeatureModel.load(tmp_path / "b" / "model.json")
    assert model.features == FeatureModel.load(tmp_path / "a" / "model.json").features


def test_trajectory_option_and_errors(
    sim_dirs: tuple[Path, Path], tmp_path: Path, cli: Cli
) -> None:
    data, _ = sim_dirs
    odo = pd.read_parquet(data / "odometry.parquet")
    odo.to_parquet(tmp_path / "trajectory.parquet")
    metrics = learn(cli, data, tmp_path / "run", "--trajectory", tmp_path / "trajectory.parquet")
    assert metrics["poses"].startswith("trajectory")

    bad = tmp_path / "bad.csv"
    bad.write_text("feature,start,end\ndoor,1,2\n")
    result = subprocess.run(  # the installed entry point: exit status 1, one line
        [sys.executable, "-m", "toolkit", "label", str(data), "--regions", str(bad), "--out", str(tmp_path / "x")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 1, result
    assert result.stderr.startswith(f"error: {bad}:2: span 1.0..2.0 is outside the log")
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
    assert not (tmp_path / "x").exists()

    code, _, err = cli("label", data, "--out", tmp_path / "y")
    assert code == 1 and "--regions" in err
    regions = ("--regions", data / "regions.csv")
    code, _, err = cli("label", data, *regions, "--out", tmp_path / "e", "--evidence-length", -1)
    assert code == 1 and "--evidence-length -1.0" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "e").exists()
    for option, value, said in (
        ("--classifier", "svm", "classifier 'svm': use one of trees, logistic"),
        ("--context", -1, "--context -1.0: a distance >= 0"),
    ):
        code, _, err = cli("label", data, *regions, "--out", tmp_path / "e", option, value)
        assert code == 1 and said in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "e").exists()
    code, _, err = cli("label", data, *regions, "--out", tmp_path / "e", "--evidence-length", 0)
    assert code == 0, err
    saved = json.loads((tmp_path / "e" / "model.json").read_text())["config"]
    assert saved["evidence_length"] is None and saved["smoothing"] == "forward-backward"
    assert saved["resemble_places"] == ["door", "window"]  # the default check
    for given, kept in (("none", []), ("doorway, window", ["doorway", "window"])):
        out = tmp_path / f"c-{len(kept)}"
        code, _, err = cli("label", data, *regions, "--out", out, "--check-places", given)
        assert code == 0, err
        assert json.loads((out / "model.json").read_text())["config"]["resemble_places"] == kept

    model = json.loads((tmp_path / "run" / "model.json").read_text())
    model["laser"]["beams"] = 361
    (tmp_path / "other.json").write_text(json.dumps(model))
    code, _, err = cli(
        "label",
        data,
        "--model",
        tmp_path / "other.json",
        "--out",
        tmp_path / "z",
    )
    assert code == 1 and "learnt on 361 beams, the dataset has 181" in err
    assert len(err.strip().splitlines()) == 1
    code, _, err = cli(
        "label", data, "--model", tmp_path / "run" / "model.json", "--out", tmp_path / "z",
        "--context", 0,
    )  # fmt: skip
    assert code == 1 and "--context is a learning setting" in err
    code, _, err = cli(
        "label", data, "--model", tmp_path / "run" / "model.json", "--out", tmp_path / "z",
        "--check-places", "door",
    )  # fmt: skip
    assert code == 1 and "--check-places is a learning setting" in err
