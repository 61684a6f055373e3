"""`toolkit simulate`: native files plus truth, written atomically; bad input is one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import toolkit.app.simulation
from tests.conftest import Cli
from toolkit.dataset import load


def test_simulate_writes_native_files_and_truth(tmp_path: Path, cli: Cli) -> None:
    config = tmp_path / "models.json"
    config.write_text(json.dumps({"wheel_diff": 0.004, "range_sigma": 0.0, "seed": 9}))
    out = tmp_path / "corridor"
    args = ["simulate", "corridor", "--out", str(out), "--format", "carmen", "--scans", "400"]
    code, _, _ = cli(*args, "--config", str(config), "--slip-prob", "0", "-p", "units=mm")
    assert code == 0
    assert {p.name for p in out.iterdir()} == {
        "sim.log", "truth.parquet", "regions.csv", "simulation.json"
    }  # fmt: skip
    record = json.loads((out / "simulation.json").read_text())
    assert record["seed"] == 9 and record["scans"] == 400
    params = record["params"]
    assert (params["wheel_diff"], params["range_sigma"], params["slip_prob"]) == (0.004, 0.0, 0.0)
    assert params["units"] == "mm" and params["scans"] == 400
    truth = pd.read_parquet(out / "truth.parquet")
    assert len(truth) == 400 and set(truth.section) == set(range(8))

    # the same log again from simulation.json as the config, in another format
    again = tmp_path / "again"
    code, _, _ = cli(
        "simulate", "corridor", "--out", str(again), "-f", "dataset",
        "--config", str(out / "simulation.json"),
    )  # fmt: skip
    assert code == 0
    ds = load(again)
    assert ds.laser.range_max == 8.0  # the mm mode
    pd.testing.assert_frame_equal(pd.read_parquet(again / "truth.parquet"), truth)


def test_existing_output_is_refused_and_kept(tmp_path: Path, cli: Cli) -> None:
    out = tmp_path / "sim"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    code, _, err_text = cli("simulate", "building", "--out", str(out), "-f", "carmen")
    assert code == 1
    assert err_text.strip() == f"error: {out}: exists; pass --force to replace it"
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--param", "range_noise=0.1"], "unknown simulator parameter"),
        (["-O", "colour=red"], "unknown option 'colour' for the rawseeds writer; known: session"),
        (["--format", "auto"], "cannot write format 'auto'; formats with a writer: aria"),
        (["--units", "inch"], "units=inch for the simulator: expected cm|mm"),
        (["-p", "beams=many"], "beams=many for the simulator: expected integer"),
        (["--scans", "1"], "scans must be at least 2"),
    ],
)
def test_bad_input_is_one_line_and_leaves_nothing(
    tmp_path: Path, args: list[str], message: str, cli: Cli
) -> None:
    out = tmp_path / "sim"
    cmd = ["simulate", "corridor", "--out", str(out), "-f", "rawseeds", "--scans", "50"]
    code, _, err_text = cli(*cmd, *args)
    err = err_text.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and message in err[0]
    assert list(tmp_path.iterdir()) == []


def test_interrupted_write_leaves_nothing(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, cli: Cli
) -> None:
    def broken(*args: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(toolkit.app.simulation, "write_truth", broken)
    out = tmp_path / "sim"
    code, _, _ = cli("simulate", "corridor", "--out", str(out), "-f", "aria", "--scans", "200")
    assert code == 1
    assert list(tmp_path.iterdir()) == []  # the native log was written, then all removed


def test_import_auto_reads_the_native_file_beside_the_truth(tmp_path: Path, cli: Cli) -> None:
    out = tmp_path / "sim"
    args = ["simulate", "building", "--out", str(out), "-f", "rawseeds", "--scans", "200"]
    assert cli(*args)[0] == 0
    dataset = tmp_path / "ds"
    assert cli("import", "auto", str(out), "--out", str(dataset), "-q")[0] == 0
    ds = load(dataset)
    truth = pd.read_parquet(out / "truth.parquet")
    assert ds.groundtruth is not None
    np.testing.assert_allclose(ds.groundtruth.x, truth.x, atol=1e-6)
    assert ds.meta["source"]["format"] == "rawseeds"


def test_building_laps_drive_the_ring_again_with_the_scans_growing(
    tmp_path: Path, cli: Cli
) -> None:
    out = tmp_path / "laps"
    code, stdout, _ = cli(
        "simulate", "building", "-p", "laps=2", "-p", "scans=2000", "--out", str(out),
        "-f", "dataset",
    )  # fmt: skip
    assert code == 0, stdout
    truth = pd.read_parquet(out / "truth.parquet")
    assert len(truth) == 2000
    # the far corner of the ring, reached once per lap
    near = np.hypot(truth.x - 40.0, truth.y - 24.0) < 0.3
    assert np.count_nonzero(np.diff(near.astype(int)) == 1) == 2
    meta = json.loads((out / "meta.json").read_text())
    assert meta["simulation"]["params"]["laps"] == 2
    code, _, err = cli(
        "simulate", "corridor", "-p", "laps=2", "--out", str(tmp_path / "c"), "-f", "dataset"
    )
    assert code == 1 and "laps" in err and "Traceback" not in err
    assert not (tmp_path / "c").exists()


def test_a_swaying_scanner_from_the_command_line_and_again_from_its_record(
    tmp_path: Path, cli: Cli
) -> None:
    out = tmp_path / "sway"
    code, stdout, _ = cli(
        "simulate", "building", "-p", "sway=0.3", "-p", "sway_period=2", "--scans", "300",
        "--out", str(out), "-f", "dataset",
    )  # fmt: skip
    assert code == 0, stdout
    record = json.loads((out / "simulation.json").read_text())["params"]
    assert (record["sway"], record["sway_period"]) == (0.3, 2.0)
    again = tmp_path / "again"
    code, _, _ = cli(
        "simulate", "building", "--out", str(again), "-f", "dataset",
        "--config", str(out / "simulation.json"),
    )  # fmt: skip
    assert code == 0
    pd.testing.assert_frame_equal(
        pd.read_parquet(again / "truth.parquet"), pd.read_parquet(out / "truth.parquet")
    )
    code, _, err = cli(
        "simulate", "corridor", "-p", "sway=-1", "--out", str(tmp_path / "c"), "-f", "dataset"
    )
    assert code == 1 and "sway must be" in err and "Traceback" not in err
    assert not (tmp_path / "c").exists()
