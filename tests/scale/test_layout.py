"""The fleet on disk: scans.parquet in row groups of ROW_GROUP_SCANS scans (the chunks the
workers read), and a fleet root hive-partitioned by dataset (`import --each`) that pandas,
pyarrow, Dask and DuckDB read without the toolkit, with a `dataset` column."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from tests.conftest import Cli
from toolkit.dataset import ROW_GROUP_SCANS, ScansWriter, load, read_scan_rows, read_scans
from toolkit.sim import simulate

pytestmark = pytest.mark.xdist_group("dask")


def test_scans_writer_cuts_row_groups_of_n_scans_whatever_the_batches(tmp_path: Path) -> None:
    ranges = simulate("corridor", scans=1000, seed=4).dataset.ranges
    t = np.arange(len(ranges), dtype=np.float64)
    path = tmp_path / "scans.parquet"
    with ScansWriter(path, ranges.shape[1], group=128) as writer:
        lo = 0
        for size in (1, 300, 7, 129, 0, 400, 163):  # batches that straddle the groups
            writer.write(t[lo : lo + size], ranges[lo : lo + size])
            lo += size
    assert lo == len(t)
    meta = pq.ParquetFile(path).metadata
    sizes = [meta.row_group(i).num_rows for i in range(meta.num_row_groups)]
    assert sizes == [128] * 7 + [1000 - 7 * 128]
    t2, r2 = read_scans(path)
    assert np.array_equal(t2, t) and np.array_equal(r2, ranges, equal_nan=True)
    # any rows, across group boundaries, from the groups that hold them only
    for start, stop in ((0, 1), (127, 129), (300, 700), (896, 1000), (0, 1000)):
        assert np.array_equal(read_scan_rows(path, start, stop), ranges[start:stop], equal_nan=True)
    with pytest.raises(Exception, match="not in this scans table"):
        read_scan_rows(path, 990, 1001)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three simulated CARMEN logs in a tree (robotA/, robotB/), imported with --each."""
    from typer.testing import CliRunner

    from toolkit.app.cli import app

    root = tmp_path_factory.mktemp("fleet")
    logs = root / "logs"
    for robot, seed, scans in (("robotA", 1, 300), ("robotA", 2, 250), ("robotB", 3, 4500)):
        run = CliRunner().invoke(
            app,
            ["simulate", "corridor", "--out", str(logs / robot / f"s{seed}"), "--format",
             "carmen", "--seed", str(seed), "--scans", str(scans)],
        )  # fmt: skip
        assert run.exit_code == 0, run.output
    run = CliRunner().invoke(
        app, ["import", "carmen", str(logs), "--each", "--out", str(root / "fleet"), "-q"]
    )
    assert run.exit_code == 0, run.output
    return root / "fleet"


def test_each_writes_a_hive_partitioned_fleet(fleet: Path) -> None:
    names = sorted(p.name for p in fleet.iterdir())
    assert names == [
        "dataset=robotA%2Fs1%2Fsim",
        "dataset=robotA%2Fs2%2Fsim",
        "dataset=robotB%2Fs3%2Fsim",
    ]
    big = fleet / names[2] / "scans.parquet"
    meta = pq.ParquetFile(big).metadata
    assert [meta.row_group(i).num_rows for i in range(meta.num_row_groups)] == [
        ROW_GROUP_SCANS,
        4500 - ROW_GROUP_SCANS,
    ]
    assert load(fleet / names[0]).n_scans == 300  # each partition is a plain dataset too


READERS = r"""
import glob, json, sys
root = sys.argv[1]
files = sorted(glob.glob(f"{root}/*/scans.parquet"))
out = {}
import pandas as pd
df = pd.read_parquet(files)
out["pandas"] = df.groupby("dataset", observed=True).size().to_dict()
first = df[df["dataset"] == "robotA/s1/sim"]["ranges"].iloc[0]
out["first_ranges"] = [None if v != v else float(v) for v in first]
import pyarrow.dataset as pads
table = pads.dataset(files, partitioning="hive", partition_base_dir=root).to_table()
out["pyarrow"] = table.group_by("dataset").aggregate([("t", "count")]).to_pydict()
import dask.dataframe as dd
ddf = dd.read_parquet(f"{root}/*/scans.parquet", split_row_groups=True)
out["dask_partitions"] = ddf.npartitions
out["dask"] = ddf.groupby("dataset", observed=True).size().compute().to_dict()
try:
    import duckdb
except ImportError:
    out["duckdb"] = None
else:
    out["duckdb"] = dict(duckdb.sql(
        f"select dataset, count(*) from read_parquet('{root}/*/scans.parquet', "
        "hive_partitioning=true) group by dataset"
    ).fetchall())
out["odometry"] = int(len(pd.read_parquet(sorted(glob.glob(f"{root}/*/odometry.parquet")))))
assert not any(m == "toolkit" or m.startswith("toolkit.") for m in sys.modules)
print(json.dumps(out))
"""


def test_engines_read_the_fleet_without_the_toolkit(fleet: Path, tmp_path: Path) -> None:
    script = tmp_path / "read.py"
    script.write_text(READERS)
    done = subprocess.run(
        [sys.executable, str(script), str(fleet)],
        capture_output=True,
        text=True,
        cwd=tmp_path,  # not the repository: `toolkit` is not importable by accident
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout)
    want = {"robotA/s1/sim": 300, "robotA/s2/sim": 250, "robotB/s3/sim": 4500}
    assert got["pandas"] == want
    assert dict(zip(got["pyarrow"]["dataset"], got["pyarrow"]["t_count"], strict=True)) == want
    assert got["dask"] == want
    assert got["dask_partitions"] == 4  # one per row group: 1 + 1 + 2
    if got["duckdb"] is not None:
        assert got["duckdb"] == want
    assert got["odometry"] == 300 + 250 + 4500
    first = load(fleet / "dataset=robotA%2Fs1%2Fsim").ranges[0]
    assert np.array_equal(np.array(got["first_ranges"], dtype=float), first, equal_nan=True)


def test_map_fleet_runs_mirror_the_names(fleet: Path, tmp_path: Path, cli: Cli) -> None:
    """`toolkit map FLEET --out RUNS`: one run per dataset under the same partition names, each
    the single-dataset run bit for bit; a re-run skips them; the runs read back as a table."""
    runs = tmp_path / "runs"
    code, out, err = cli("map", fleet, "--out", runs, "--method", "odometry")
    assert (code, err) == (0, "")
    assert "3 written, 0 skipped (complete), 0 failed, of 3 datasets" in out
    assert sorted(p.name for p in runs.iterdir()) == sorted(p.name for p in fleet.iterdir())
    name = "dataset=robotA%2Fs2%2Fsim"
    code, _, err = cli("map", fleet / name, "--out", tmp_path / "one", "--method", "odometry")
    assert code == 0, err
    assert (runs / name / "trajectory.tum").read_bytes() == (
        tmp_path / "one" / "trajectory.tum"
    ).read_bytes()
    code, out, _ = cli("map", fleet, "--out", runs, "--method", "odometry")
    assert code == 0 and "0 written, 3 skipped (complete)" in out
    import pandas as pd

    table = pd.read_parquet(sorted(runs.glob("*/trajectory.parquet")))  # type: ignore[call-overload]
    assert table.groupby("dataset", observed=True).size().to_dict()["robotB/s3/sim"] == 4500
