"""CARMEN import streamed to Parquet (`Carmen.import_to`): the same dataset, table for table,
that `read` + `save` give, on the real logs, the simulator's log and a damaged copy; and
memory for the data that does not grow with the log."""

from __future__ import annotations

import json
import tempfile
import tracemalloc
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import importers.base
from importers import carmen
from importers.carmen import Carmen, CarmenOptions, write_log
from tests.importers.test_carmen import LOGS, RADISH
from toolkit.dataset import Dataset, column_numpy, save
from toolkit.sim import Simulation


def _values(column: pa.ChunkedArray) -> np.ndarray:
    arr = column.combine_chunks()
    if isinstance(arr, pa.FixedSizeListArray):  # ranges
        return column_numpy(arr.values).reshape(len(arr), -1)
    return column_numpy(arr)


def assert_same_dataset(a: Path, b: Path) -> None:
    """Same files; each table with the same schema (fields, units, schema metadata) and the
    same values to the bit (NaN where NaN); meta.json the same but for its creation time."""
    files = sorted(p.name for p in a.iterdir())
    assert files == sorted(p.name for p in b.iterdir())
    for name in files:
        if name.endswith(".parquet"):
            ta, tb = pq.read_table(a / name), pq.read_table(b / name)
            assert ta.schema.equals(tb.schema, check_metadata=True), name
            assert ta.num_rows == tb.num_rows, name
            for col in ta.column_names:
                va, vb = _values(ta.column(col)), _values(tb.column(col))
                assert va.dtype == vb.dtype and va.shape == vb.shape, (name, col)
                assert np.array_equal(va, vb, equal_nan=True), (name, col)
        else:
            ma, mb = (json.loads((d / name).read_text()) for d in (a, b))
            ma.pop("created"), mb.pop("created")
            assert ma == mb, name


@pytest.fixture
def small_spill(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Spill every few kB, in small ODOM blocks and row groups, so that the file path, block
    edges and several pose row groups are exercised on small logs; counts the spill files."""
    monkeypatch.setattr(importers.base, "SPILL_BLOCK_BYTES", 4096)
    monkeypatch.setattr(carmen, "POSE_BLOCK", 1000)
    monkeypatch.setattr(carmen, "POSE_GROUP", 3000)
    opened: list[int] = []
    real_temporary = tempfile.TemporaryFile

    def counted(*args: object, **kwargs: object) -> object:
        opened.append(1)
        return real_temporary(*args, **kwargs)  # type: ignore[call-overload]

    monkeypatch.setattr(importers.base.tempfile, "TemporaryFile", counted)
    return opened


def _both(src: Path, tmp: Path, options: CarmenOptions) -> tuple[Path, Path]:
    streamed, whole = tmp / "streamed", tmp / "whole"
    Carmen().import_to([src], streamed, options)
    save(Carmen().read([src], options), whole)
    return streamed, whole


@pytest.mark.parametrize("rel", LOGS)
def test_streamed_real_log_equals_the_whole_one(
    real: Path, rel: str, tmp_path: Path, small_spill: list[int]
) -> None:
    streamed, whole = _both(real / rel, tmp_path, CarmenOptions())
    assert small_spill, "nothing went through a spill file"
    assert_same_dataset(streamed, whole)


def test_streamed_groundtruth_option_equals_the_whole_one(
    real: Path, tmp_path: Path, small_spill: list[int]
) -> None:
    src = real / RADISH / "intel-corrected.log.gz"
    streamed, whole = _both(src, tmp_path, CarmenOptions(poses="groundtruth"))
    assert_same_dataset(streamed, whole)
    assert (streamed / "poses-scan_pose.parquet").exists() is False
    assert (streamed / "groundtruth.parquet").exists()


def test_streamed_damaged_simulated_log_equals_the_whole_one(
    corridor_sim: Simulation, tmp_path: Path, small_spill: list[int]
) -> None:
    """The simulator's log (odometry, truth) with damage each pass must agree on: NaN, inf and
    negative ranges, an ODOM line stamped 0 (out of order), an implausible odometry pose
    (dropped when written), a TRUEPOS line with a non-finite value, a truncated last line."""
    (log,) = Carmen().write(corridor_sim.dataset, tmp_path / "src")
    lines = log.read_text().splitlines()
    flaser = [i for i, ln in enumerate(lines) if ln.startswith("FLASER ")]
    odom = [i for i, ln in enumerate(lines) if ln.startswith("ODOM ")]
    truepos = [i for i, ln in enumerate(lines) if ln.startswith("TRUEPOS ")]
    tokens = lines[flaser[10]].split()
    tokens[5], tokens[6], tokens[7] = "nan", "inf", "-1.0"
    lines[flaser[10]] = " ".join(tokens)
    tokens = lines[odom[50]].split()
    tokens[-1] = tokens[-3] = "0.000000"
    lines[odom[50]] = " ".join(tokens)
    tokens = lines[odom[len(odom) // 2 + 7]].split()
    tokens[1] = "7.9e9"
    lines[odom[len(odom) // 2 + 7]] = " ".join(tokens)
    tokens = lines[truepos[20]].split()
    tokens[2] = "nan"
    lines[truepos[20]] = " ".join(tokens)
    log.write_text("\n".join(lines)[:-40])
    streamed, whole = _both(log, tmp_path, CarmenOptions())
    assert_same_dataset(streamed, whole)
    report = json.loads((streamed / "meta.json").read_text())["import_report"]
    dropped = report["dropped"]
    assert dropped["ODOM timestamp out of order"] == 1
    assert dropped["TRUEPOS NaN or inf value"] == 1
    assert any(k.startswith("odometry: implausible pose") for k in dropped)
    assert dropped["truncated last line"] == 1
    assert any("3 range values NaN, inf or negative" in n for n in report["notes"])


def _tiled(ds: Dataset, copies: int) -> Dataset:
    """`ds` `copies` times in a row, each later by the log's duration + 1 s."""
    assert ds.odometry is not None
    span = float(ds.t[-1] - ds.t[0]) + 1.0
    odo = ds.odometry.loc[np.tile(np.arange(len(ds.odometry)), copies)].reset_index(drop=True)
    odo["t"] = odo["t"].to_numpy() + np.repeat(np.arange(copies) * span, len(ds.odometry))
    return Dataset(
        t=np.tile(ds.t, copies) + np.repeat(np.arange(copies) * span, len(ds.t)),
        ranges=np.tile(ds.ranges, (copies, 1)),
        laser=ds.laser,
        odometry=odo,
    )


def test_memory_for_the_data_does_not_grow_with_the_log(real: Path, tmp_path: Path) -> None:
    """The Python and numpy memory (tracemalloc) an import peaks at, on the intel log (1.9 MB
    of text) and on it ten times over (19 MB, 9060 scans, 10x the ODOM lines): before the
    streaming import, 11.5 and 29.3 MB (2.5x); the 10x log may cost at most 1.75x the 1x one
    (what grows is 9-17 bytes per ODOM line and ~100 per scan, not the ranges)."""
    ds = Carmen().read([real / RADISH / "intel-corrected.log.gz"], CarmenOptions())
    peaks = []
    for copies in (1, 10):
        log = tmp_path / f"x{copies}.log"
        write_log(_tiled(ds, copies), log)
        tracemalloc.start()
        try:
            Carmen().import_to([log], tmp_path / f"ds{copies}", CarmenOptions())
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
        log.unlink()
    assert pq.ParquetFile(tmp_path / "ds10" / "scans.parquet").metadata.num_rows == 10 * ds.n_scans
    assert peaks[1] < 1.75 * peaks[0], [round(p / 2**20, 1) for p in peaks]
