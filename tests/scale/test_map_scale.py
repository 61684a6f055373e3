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
from toolkit.app.fleet import client_for, parse_scheduler
from toolkit.app.fleet_map import chunk_plan, match_pairs_on, matcher_for, pair_chunks
from toolkit.dataset import Dataset, load, save
from toolkit.poses import build
from toolkit.sim import simulate
from toolkit.slam.run import slam_trajectory

pytestmark = pytest.mark.xdist_group("dask")  # one cluster at a time under --dist loadgroup


@pytest.fixture(scope="module")
def log() -> Dataset:
    """A simulated building log with drifting odometry (keyframes) and ground truth."""
    return simulate("building", scans=700, seed=3).dataset


@pytest.fixture(scope="module")
def single(log: Dataset, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pd.DataFrame]:
    """The dataset directory and its single-process trajectory.parquet."""
    from toolkit.mapping import map_run

    root = tmp_path_factory.mktemp("scale")
    data = save(replace(log), root / "ds")
    run = map_run(data, root / "one").path
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


def test_chunks_are_row_groups_and_start_at_their_keyframe(log: Dataset) -> None:
    from toolkit.align import scan as sc
    from toolkit.poses import odometry_poses

    odo = odometry_poses(log)
    assert odo is not None
    ref = sc.keyframes(odo, 0.3, 0.2)
    chunks = pair_chunks(ref, 100)
    # chunk k: the pairs whose current scans are 100k .. 100k+99 (row group k)
    assert [(lo + 1, hi) for _, lo, hi in chunks][:3] == [(1, 99), (100, 199), (200, 299)]
    assert chunks[-1][2] == log.n_scans - 1
    for first, lo, _ in chunks:
        assert first == ref[lo + 1] <= lo  # overlap back to the keyframe, at least one scan
    assert any(first < lo for first, lo, _ in chunks[1:])  # the keyframe case occurs here


def test_chunk_plan_with_several_earlier_references() -> None:
    """References that are neither keyframes nor consecutive: every earlier one is shipped,
    the pairs between them are dropped, the chunk's own pairs keep their seeds."""
    refs = np.array([0, 0, 0, 1, 1, 2, 4, 6])
    seeds = np.arange(21.0).reshape(7, 3)
    earlier, ref, local_seeds, skip = chunk_plan(refs, seeds, 3, 7)  # pairs 3..6: scans 4..7
    assert earlier.tolist() == [1, 2]
    assert skip == 1
    # small log: [scan 1, scan 2, scan 4, scan 5, scan 6, scan 7]
    assert ref.tolist() == [0, 0, 0, 1, 2, 4]
    assert np.array_equal(local_seeds[skip:], seeds[3:7])


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


def test_workers_reading_their_row_groups_give_the_same_trajectory(
    log: Dataset, client: object, tmp_path: Path
) -> None:
    """The scans read by the workers from scans.parquet (row groups of 100 scans here), by
    whole row groups and by chunks that cut across them: the single-process poses."""
    from toolkit.dataset import SCANS, ScansWriter

    scans = tmp_path / SCANS
    with ScansWriter(scans, log.n_beams, group=100) as writer:
        writer.write(log.t, log.ranges)
    alone = build(log)
    for chunk in (None, 97):  # None: the file's row group, one per task
        spread = build(log, matcher=matcher_for(client, chunk, scans=scans))  # type: ignore[arg-type]
        assert np.array_equal(alone.poses, spread.poses)
    other = tmp_path / "other.parquet"
    with ScansWriter(other, log.n_beams) as writer:
        writer.write(log.t[:-1], log.ranges[:-1])
    with pytest.raises(Exception, match="has not the 700 scans"):
        build(log, matcher=matcher_for(client, scans=other))  # type: ignore[arg-type]


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


@pytest.mark.slow
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


def _part(ds: Dataset, lo: int, hi: int) -> Dataset:
    """Scans lo..hi-1 of `ds` with their odometry and ground truth: a log of its own."""

    def cut(frame: pd.DataFrame | None) -> pd.DataFrame | None:
        if frame is None:
            return None
        return frame[(frame.t >= ds.t[lo]) & (frame.t <= ds.t[hi - 1])]

    return Dataset(ds.t[lo:hi], ds.ranges[lo:hi], ds.laser, cut(ds.odometry), cut(ds.groundtruth))


@pytest.fixture(scope="module")
def fleet(log: Dataset, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """dataset=east and dataset=west (two parts of the log) and dataset=broken (its
    scans.parquet cut short: a damaged copy)."""
    root = tmp_path_factory.mktemp("fleet")
    save(_part(log, 0, 400), root / "dataset=east")
    save(_part(log, 300, 700), root / "dataset=west")
    broken = root / "dataset=broken"
    save(_part(log, 0, 100), broken)
    scans = (broken / "scans.parquet").read_bytes()
    (broken / "scans.parquet").write_bytes(scans[: len(scans) // 2])
    return root


@pytest.mark.slow
def test_map_fleet_damaged_dataset_by_name_cluster_same_runs_rerun_skips(
    fleet: Path, tmp_path: Path, cli: Cli
) -> None:
    here, there = tmp_path / "here", tmp_path / "there"
    code, out, err = cli("map", fleet, "--out", here)
    assert code == 1
    failures = err.strip().splitlines()
    assert len(failures) == 1 and "Traceback" not in err
    assert failures[0].startswith(f"failed: {(fleet / 'dataset=broken').resolve()}: ")
    assert "2 written, 0 skipped (complete), 1 failed, of 3 datasets" in out
    assert sorted(p.name for p in here.iterdir()) == ["dataset=east", "dataset=west"]
    # one task per dataset on a LocalCluster: the same failure, the same runs bit for bit
    code, out, err = cli("map", fleet, "--out", there, "--scheduler", "local:2")
    assert code == 1 and len(err.strip().splitlines()) == 1 and "dataset=broken" in err
    for name in ("dataset=east", "dataset=west"):
        a = pd.read_parquet(here / name / "trajectory.parquet")
        b = pd.read_parquet(there / name / "trajectory.parquet")
        assert np.array_equal(a.to_numpy(), b.to_numpy())
    # and each is the single-dataset run
    code, _, err = cli("map", fleet / "dataset=west", "--out", tmp_path / "west", "-q")
    assert code == 0, err
    assert (tmp_path / "west" / "trajectory.tum").read_bytes() == (
        here / "dataset=west" / "trajectory.tum"
    ).read_bytes()
    # re-run: complete runs of unchanged datasets are skipped, a changed one is mapped again
    pattern = str(fleet / "dataset=[ew]*")  # a quoted glob, without the broken one
    code, out, err = cli("map", pattern, "--out", here)
    assert (code, err) == (0, "")
    assert "0 written, 2 skipped (complete), 0 failed, of 2 datasets" in out
    meta = fleet / "dataset=east" / "meta.json"
    kept = meta.read_text()
    meta.write_text(kept.replace('"scans"', '"scans" ', 1))  # re-imported: another meta.json
    try:
        code, out, _ = cli("map", pattern, "--out", here)
        assert code == 0 and "1 written, 1 skipped (complete)" in out
        code, out, _ = cli("map", pattern, "--out", here, "--method", "odometry")
        assert code == 0 and "2 written, 0 skipped (complete)" in out
    finally:
        meta.write_text(kept)


def test_map_cli_unreachable_scheduler_is_one_line(
    single: tuple[Path, pd.DataFrame], tmp_path: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("toolkit.app.fleet.CONNECT_TIMEOUT", "1s")
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


@pytest.mark.slow
def test_map_on_dask_scheduler_and_two_workers(
    single: tuple[Path, pd.DataFrame], fleet: Path, tmp_path: Path, cli: Cli
) -> None:
    """`dask scheduler` + two `dask worker` processes on loopback, as on a real cluster: one
    dataset's pairs in chunks, the workers reading their scans from scans.parquet; then a
    fleet, one dataset per task, the damaged one reported by name."""
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
        runs = tmp_path / "runs"
        code, out, err = cli("map", fleet, "--out", runs, "--scheduler", address)
        assert code == 1 and "2 written, 0 skipped (complete), 1 failed, of 3 datasets" in out
        assert len(err.strip().splitlines()) == 1 and "dataset=broken" in err
        east = pd.read_parquet(runs / "dataset=east" / "trajectory.parquet")
        alone = slam_trajectory(load(fleet / "dataset=east"))[0]  # the default: with loops
        assert np.array_equal(east.to_numpy(), alone.frame.to_numpy())
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
