"""Issue 19 items 3 and 5: bad input is refused with one line, never blocks, never takes
unbounded memory, never becomes an implausible dataset."""

from __future__ import annotations

import gzip
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT, Cli
from toolkit.dataset import Dataset

ENV = {**os.environ, "TOOLKIT_NO_PROGRESS": "1"}


def run(*args: object, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """`toolkit ARGS` in a process with a deadline (a blocked read fails the test) and an
    address-space cap of 2 GB (unbounded reading fails it too)."""
    limit = "import resource; resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30));"
    code = (
        limit
        + "import runpy, sys; sys.argv = ['toolkit', *sys.argv[1:]]; runpy.run_module('toolkit', run_name='__main__')"
    )
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], env=ENV,
                          capture_output=True, text=True, timeout=timeout)  # fmt: skip


def one_line(res: subprocess.CompletedProcess[str], *expected: str) -> str:
    err = res.stderr.strip()
    assert res.returncode == 1, err
    assert len(err.splitlines()) == 1, err
    assert "internal error" not in err and "Traceback" not in err, err
    for text in expected:
        assert text in err, err
    return err


@pytest.mark.parametrize("fmt", ["auto", "carmen", "aria", "table", "rawseeds", "lms200", "rosbag"])
def test_a_fifo_is_refused_not_read(tmp_path: Path, fmt: str) -> None:
    fifo = tmp_path / "log.fifo"
    os.mkfifo(fifo)
    one_line(run("import", fmt, fifo, "--out", tmp_path / "ds"), f"{fifo}: is a FIFO")


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_a_device_is_refused(tmp_path: Path, device: str) -> None:
    one_line(run("import", "carmen", device, "--out", tmp_path / "ds"), "is a device")


def test_a_fifo_in_an_each_directory_is_skipped(small: dict[str, Path], tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    shutil.copy(small["log"], logs / "a.log")
    os.mkfifo(logs / "b.log")
    res = run("import", "carmen", logs, "--each", "--out", tmp_path / "fleet")
    assert res.returncode == 0, res.stderr
    assert "1 written" in res.stdout
    assert [p.name for p in (tmp_path / "fleet").iterdir()] == ["dataset=a"]


def test_a_gzip_bomb_is_refused(tmp_path: Path) -> None:
    """1 MB of gzip that would decompress to ~1 GB of laser lines: stopped at 50x."""
    line = b"FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 1.5 h 1.5\n"
    bomb = tmp_path / "bomb.log.gz"
    with gzip.open(bomb, "wb", compresslevel=9) as f:
        block = line * (1 << 16)
        for _ in range(1 << 8):  # 2.8 MB * 256 = 720 MB of text
            f.write(block)
    assert bomb.stat().st_size < 4 << 20
    one_line(run("import", "carmen", bomb, "--out", tmp_path / "ds", timeout=300),
             "decompresses to more than 50x its size")  # fmt: skip


@pytest.mark.parametrize("fmt", ["carmen", "aria", "table"])
def test_zeros_are_refused_by_line_length(tmp_path: Path, fmt: str) -> None:
    """A gzip of NULs (no newline ever): a line longer than 1 MB, not a read of all of it."""
    zeros = tmp_path / "zeros.gz"
    zeros.write_bytes(gzip.compress(bytes(30 << 20)))
    one_line(run("import", fmt, zeros, "--out", tmp_path / "ds"), "a line longer than 1 MB")


def test_rawseeds_invalid_utf8_is_one_line(tmp_path: Path) -> None:
    session = tmp_path / "s"
    session.mkdir()
    import bz2

    for src in (ROOT / "datasets" / "building-rawseeds").glob("*.csv.bz2"):
        (session / src.name.removesuffix(".bz2")).write_bytes(bz2.decompress(src.read_bytes()))
    laser = next(session.glob("*SICK_FRONT.csv"))
    lines = laser.read_bytes().split(b"\n")
    lines[5] = b"1.0,\xff\xfe,abc" + lines[5][10:]
    laser.write_bytes(b"\n".join(lines))
    err = one_line(run("import", "rawseeds", session, "--out", tmp_path / "ds"))
    assert err == f"error: {laser}:6: not a number: byte 0xff"


def test_an_implausible_odometry_is_dropped_and_counted(
    small: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    """A rosbag whose odometry reads x = 7.9e165 m (and another NaN): those poses are
    dropped and counted; the rest imports."""
    import importers
    import toolkit

    ds = toolkit.load(small["dataset"])
    assert ds.odometry is not None
    odo = ds.odometry.copy()
    odo.loc[10, "x"] = 7.9e165
    odo.loc[20, "y"] = np.nan
    ds.odometry = odo
    bag = importers.get("rosbag").write(ds, tmp_path / "bag")[0]
    code, _, err = cli("import", "rosbag", bag, "--out", tmp_path / "ds", "-q")
    assert code == 0, err
    back = toolkit.load(tmp_path / "ds")
    assert back.odometry is not None and len(back.odometry) == len(odo) - 2
    assert np.abs(back.odometry[["x", "y"]].to_numpy()).max() < 1e3
    dropped = back.report.dropped  # the NaN one never reaches the checks (writer or reader)
    assert dropped["odometry: implausible pose (non-finite, or beyond 1e+06 m)"] == 1


def test_scan_times_going_backwards_are_an_error(tmp_path: Path) -> None:
    from toolkit.dataset import Dataset, LaserGeometry, save
    from toolkit.errors import FormatError

    t = np.array([0.0, 1.0, 0.5, 2.0])
    ds = Dataset(t, np.ones((4, 3), np.float32), LaserGeometry(3, -1.0, 1.0, 10.0))
    with pytest.raises(FormatError, match=r"scan times go backwards at scan 2 \(1.0 -> 0.5 s\)"):
        save(ds, tmp_path / "ds")
    assert list(tmp_path.iterdir()) == []
    ds.t = np.array([0.0, 1.0, 2.0, 3.0])
    ds.ranges = np.array([[1, -2, np.inf]] * 4, np.float32)
    save(ds, tmp_path / "ok")
    assert np.isnan(toolkit_load(tmp_path / "ok").ranges[:, 1:]).all()


def toolkit_load(path: Path) -> Dataset:
    import toolkit

    return toolkit.load(path)


def test_table_in_blocks_equals_table_whole(
    small: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The table importer reads in blocks of lines: the same dataset whatever the block."""
    import importers
    from importers import table

    src = importers.get("table").write(toolkit_load(small["dataset"]), tmp_path / "t")[0]
    lines = src.read_text().splitlines(keepends=True)
    lines[40] = "1.0,garbage\n"  # a bad row in the middle
    src.write_text("".join(lines))
    whole = importers.get("table").read([src], importers.read_options(importers.get("table"), None))
    monkeypatch.setattr(table, "TABLE_BLOCK", 4096)
    blocks = importers.get("table").read(
        [src], importers.read_options(importers.get("table"), None)
    )
    np.testing.assert_array_equal(whole.ranges, blocks.ranges)
    np.testing.assert_array_equal(whole.t, blocks.t)
    assert whole.report.records_dropped == blocks.report.records_dropped == 1
