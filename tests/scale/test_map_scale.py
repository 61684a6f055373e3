"""`toolkit map --scheduler`: the pairs matched on a real Dask cluster give the single-process
trajectory bit for bit (LocalCluster and a `dask scheduler` + two `dask worker` processes)."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tests.conftest import Cli
from toolkit.dataset import Dataset, save
from toolkit.poses import build
from toolkit.scale import client_for, match_pairs_on, matcher_for, pair_chunks, parse_scheduler
from toolkit.sim import simulate

pytestmark = pytest.mark.xdist_group("dask")  # one cluster at a time under --dist loadgroup


@pytest.fixture(scope="module")
def log() -> Dataset:
    """A simulated building log with drifting odometry (keyframes) and ground truth."""
    return simulate("building", scans=700, seed=3).dataset


@pytest.fixture(scope="module")
def single(log: Dataset, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pd.DataFrame]:
    """The dataset directory and its single-process trajectory.parquet."""
    from toolkit.mapping import map_dataset

    root = tmp_path_factory.mktemp("scale")
    data = save(replace(log), root / "ds")
    run = map_dataset(data, root / "one")
    return data, pd.read_parquet(run / "trajectory.parquet")


@pytest.fixture(scope="module")
def client() -> Iterator[object]:
    with client_for("local:2") as c:
        yield c


def test_parse_scheduler() -> None:
    assert parse_scheduler(None) == ("none", 1)
    assert parse_scheduler("none") == ("none", 1)
    assert parse_scheduler("local:3") == ("local", 3)
    assert parse_scheduler("tcp://10.0.0.1:8786") == ("tcp://10.0.0.1:8786", 0)


def test_chunks_start_at_the_keyframe_of_their_first_pair(log: Dataset) -> None:
    from toolkit.align import scan as sc
    from toolkit.poses import odometry_poses

    odo = odometry_poses(log)
    assert odo is not None
    ref = sc.keyframes(odo, 0.3, 0.2)
    chunks = pair_chunks(ref, 100)
    assert [lo for _, lo, _ in chunks] == list(range(0, log.n_scans - 1, 100))
    assert chunks[-1][2] == log.n_scans - 1
    for first, lo, _ in chunks:
        assert first == ref[lo + 1] <= lo  # overlap back to the keyframe, at least one scan
    assert any(first < lo for first, lo, _ in chunks[1:])  # the keyframe case occurs here


@pytest.mark.parametrize("odometry", [True, False], ids=["keyframes", "consecutive"])
def test_cluster_trajectory_equals_single_process(
    log: Dataset, client: object, odometry: bool
) -> None:
    ds = log if odometry else replace(log, odometry=None)
    alone = build(ds)
    assert alone.matches is not None
    for chunk in (97, 400):  # chunk boundaries anywhere: inside keyframe spans, uneven tail
        spread = build(ds, matcher=matcher_for(client, chunk))  # type: ignore[arg-type]
        assert spread.matches is not None
        assert np.array_equal(alone.poses, spread.poses)
        assert np.array_equal(alone.matches.pose, spread.matches.pose)
        assert np.array_equal(alone.matches.covariance, spread.matches.covariance)
        assert np.array_equal(alone.matches.degenerate, spread.matches.degenerate)


def test_cluster_matching_is_real_work(log: Dataset, client: object) -> None:
    """The cluster path is not a pass-through: wrong inputs give different poses."""
    from toolkit.align import scan as sc

    n = 200
    seeds = np.zeros((n - 1, 3))
    good = match_pairs_on(client, log.ranges[:n], seeds, log.laser, chunk=50)  # type: ignore[arg-type]
    shuffled = match_pairs_on(client, log.ranges[:n][::-1].copy(), seeds, log.laser, chunk=50)  # type: ignore[arg-type]
    assert len(good) == n - 1
    assert np.array_equal(good.pose, sc.match_pairs(log.ranges[:n], seeds, log.laser).pose)
    assert not np.array_equal(good.pose, shuffled.pose)


def test_map_cli_local_cluster_same_trajectory(
    single: tuple[Path, pd.DataFrame], tmp_path: Path, cli: Cli
) -> None:
    data, one = single
    code, _, err = cli("map", data, "--out", tmp_path / "two", "--scheduler", "local:2", "-q")
    assert code == 0, err
    two = pd.read_parquet(tmp_path / "two" / "trajectory.parquet")
    assert list(two.columns) == list(one.columns)
    assert np.array_equal(one.to_numpy(), two.to_numpy())
    assert (data.parent / "one" / "trajectory.tum").read_bytes() == (
        tmp_path / "two" / "trajectory.tum"
    ).read_bytes()


def test_map_cli_unreachable_scheduler_is_one_line(
    single: tuple[Path, pd.DataFrame], tmp_path: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("toolkit.scale.CONNECT_TIMEOUT", "1s")
    data, _ = single
    port = _free_port()
    code, _, err = cli(
        "map", data, "--out", tmp_path / "run", "--scheduler", f"tcp://127.0.0.1:{port}"
    )
    assert code == 1
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "scheduler" in err
    assert not (tmp_path / "run").exists()


def test_map_cli_scheduler_needs_the_gaussian_matcher(
    single: tuple[Path, pd.DataFrame], tmp_path: Path, cli: Cli
) -> None:
    data, _ = single
    code, _, err = cli(
        "map", data, "--out", tmp_path / "run", "--method", "icp", "--scheduler", "local:2"
    )
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert "--scheduler" in err and "icp" in err
    assert not (tmp_path / "run").exists()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_map_on_dask_scheduler_and_two_workers(
    single: tuple[Path, pd.DataFrame], tmp_path: Path, cli: Cli
) -> None:
    """`dask scheduler` + two `dask worker` processes on loopback, as on a real cluster."""
    dask = str(Path(sys.executable).parent / "dask")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = [(tmp_path / f"{name}.log").open("w") for name in ("scheduler", "worker0", "worker1")]
    procs = [
        subprocess.Popen(
            [
                dask,
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                str(port),
                "--dashboard-address",
                ":0",
                "--no-show",
            ],
            stdout=subprocess.DEVNULL,
            stderr=logs[0],  # kept in tmp_path by pytest, to read after a failure
        )
    ]
    try:
        procs += [
            subprocess.Popen(
                [
                    dask,
                    "worker",
                    address,
                    "--nthreads",
                    "1",
                    "--no-dashboard",
                    "--host",
                    "127.0.0.1",
                ],
                stdout=subprocess.DEVNULL,
                stderr=logs[1 + i],
            )
            for i in range(2)
        ]
        from distributed import Client

        with Client(address, timeout="60s") as c:
            c.wait_for_workers(2, timeout=120)
            assert len(c.scheduler_info()["workers"]) == 2
        data, one = single
        code, _, err = cli("map", data, "--out", tmp_path / "two", "--scheduler", address, "-q")
        assert code == 0, err
        two = pd.read_parquet(tmp_path / "two" / "trajectory.parquet")
        assert np.array_equal(one.to_numpy(), two.to_numpy())
    finally:
        for p in reversed(procs):
            p.terminate()
        deadline = time.monotonic() + 10
        for p in procs:
            try:
                p.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                p.kill()
        for log in logs:
            log.close()
