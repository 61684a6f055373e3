"""Issue 19 items 1, 2 (stale temp folders, label), 4 (dashboard), 5 (--trajectory), 6:
nothing lost without --force, one writer per output, errors that name the problem."""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np
import pandas as pd
import pytest

from tests.conftest import Cli
from tests.faults.conftest import digest, hidden
from toolkit.atomic import atomic_dir, atomic_file, output_lock, writer_threads
from toolkit.errors import OutputExistsError, ToolkitError

T = TypeVar("T")


def _fleet(small: dict[str, Path], tmp_path: Path) -> Path:
    """A directory of two logs, for --each."""
    logs = tmp_path / "logs"
    logs.mkdir()
    shutil.copy(small["log"], logs / "a.log")
    shutil.copy(small["log"], logs / "b.log")
    return logs


# ---------------------------------------------------------------- item 1: nothing lost


def test_fleet_import_keeps_a_users_directory(
    small: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    logs = _fleet(small, tmp_path)
    fleet = tmp_path / "fleet"
    mine = fleet / "dataset=a"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("keep me")
    code, _, err = cli("import", "carmen", logs, "--each", "--out", fleet, "-q")
    assert code == 1
    assert "dataset=a: exists and is not the toolkit's output; pass --force" in err
    assert (mine / "notes.txt").read_text() == "keep me"
    assert (fleet / "dataset=b" / "meta.json").is_file()  # the other log was imported
    code, _, err = cli("import", "carmen", logs, "--each", "--out", fleet, "-q", "--force")
    assert code == 0, err
    assert not (mine / "notes.txt").exists()


def test_fleet_import_replaces_its_own_stale_dataset(
    small: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    """A dataset whose source changed is the toolkit's own output: replaced without --force."""
    logs = _fleet(small, tmp_path)
    fleet = tmp_path / "fleet"
    assert cli("import", "carmen", logs, "--each", "--out", fleet, "-q")[0] == 0
    with open(logs / "a.log", "a") as f:
        f.write("# one more line\n")
    code, out, err = cli("import", "carmen", logs, "--each", "--out", fleet)
    assert code == 0, err
    assert "1 written, 1 skipped" in out


def test_fleet_map_keeps_a_users_directory(
    small: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    runs = tmp_path / "runs"
    mine = runs / "ds"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("keep me")
    other = tmp_path / "ds2"
    shutil.copytree(small["dataset"], other)
    code, _, err = cli("map", small["dataset"], other, "--out", runs, "--method", "odometry", "-q")
    assert code == 1
    assert "ds: exists and is not the toolkit's output; pass --force" in err
    assert (mine / "notes.txt").read_text() == "keep me"
    assert (runs / "ds2" / "metrics.json").is_file()


# ---------------------------------------------------------------- one writer, stale temps


def test_two_writers_to_one_output_cannot_both_succeed(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with atomic_dir(out) as tmp:
        (tmp / "a").write_text("first")
        busy = pytest.raises(ToolkitError, match="another toolkit command is writing it now")
        with busy, atomic_dir(out, force=True):
            pass
    assert (out / "a").read_text() == "first"
    with pytest.raises(OutputExistsError), atomic_dir(out):  # after it: refused without --force
        pass
    assert hidden(tmp_path) == []


def test_concurrent_cli_writers(small: dict[str, Path], tmp_path: Path, cli: Cli) -> None:
    """A second import to the OUT another one is writing fails with one line."""
    out = tmp_path / "ds"
    with output_lock(out):
        code, _, err = cli("import", "carmen", small["log"], "--out", out)
    assert code == 1
    assert (
        err.strip()
        == f"error: {out}: another toolkit command is writing it now; wait for it or stop it"
    )
    assert not out.exists()


def _signal_after(real: Callable[..., T]) -> Callable[..., T]:
    """`real`, then SIGINT to this process: the signal lands right after the temporary exists,
    before the caller has recorded its name (the window CI once hit)."""

    def call(*args: object, **kwargs: object) -> T:
        result = real(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)
        return result

    return call


@pytest.mark.parametrize("make", ["mkdtemp", "mkstemp"])
def test_a_signal_as_the_temporary_is_created_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, make: str
) -> None:
    monkeypatch.setattr(tempfile, make, _signal_after(getattr(tempfile, make)))
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "kept").write_text("the user's")
    writer = (
        atomic_dir(tmp_path / "out", update=True)
        if make == "mkdtemp"
        else atomic_file(tmp_path / "out" / "kept")
    )
    with pytest.raises(KeyboardInterrupt), writer as tmp:
        Path(tmp, "new").write_text("x") if make == "mkdtemp" else Path(tmp).write_text("x")
    assert hidden(tmp_path) == []
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["kept"]
    assert (tmp_path / "out" / "kept").read_text() == "the user's"


def test_a_signal_between_the_renames_keeps_the_output(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Replacing an output is two renames (old -> trash, new -> out): a signal between them
    waits, so OUT is the old or the new directory, never missing."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "v").write_text("old")
    monkeypatch.setattr(os, "replace", _signal_after(os.replace))
    with pytest.raises(KeyboardInterrupt), atomic_dir(out, force=True) as tmp:
        (tmp / "v").write_text("new")
    assert (out / "v").read_text() in ("old", "new")
    assert hidden(tmp_path) == []


def test_a_signal_while_writers_finish_waits_for_them(tmp_path: Path) -> None:
    """`toolkit map` writes its outputs in threads. A Ctrl-C that lands while the block waits
    for them must not leave a writer running while `atomic_dir` removes the temporary
    directory: its late file would keep the directory (make test once saw that). The stop
    comes from a second thread while the main thread waits in the pool's exit."""
    done = threading.Event()

    def late_writer(folder: Path) -> None:
        time.sleep(0.4)
        (folder / "late.bin").write_bytes(b"x")
        done.set()

    def stop_soon() -> None:
        time.sleep(0.1)
        os.kill(os.getpid(), signal.SIGINT)

    with (
        pytest.raises(KeyboardInterrupt),
        atomic_dir(tmp_path / "out") as tmp,
        writer_threads(2) as pool,
    ):
        pool.submit(late_writer, tmp)
        threading.Thread(target=stop_soon).start()
    assert done.is_set()  # the writer had ended before the cleanup
    assert hidden(tmp_path) == []
    assert not (tmp_path / "out").exists()


def test_a_signal_inside_submit_still_waits_for_that_writer(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Starting a pool thread waits for it: a Ctrl-C there leaves `submit` after the work was
    queued and its thread started, before the future came back (a fresh-clone CI run left
    `cloud.ply` and `cloud.pcd` in `.run.*.tmp` that way; 2 of 25 stopped map runs)."""
    from concurrent.futures import ThreadPoolExecutor

    start_threads = ThreadPoolExecutor._adjust_thread_count

    def start_then_stop(self: ThreadPoolExecutor) -> None:
        start_threads(self)
        raise KeyboardInterrupt

    monkeypatch.setattr(ThreadPoolExecutor, "_adjust_thread_count", start_then_stop)
    done = threading.Event()

    def late_writer(folder: Path) -> None:
        time.sleep(0.3)
        (folder / "late.bin").write_bytes(b"x")
        done.set()

    with (
        pytest.raises(KeyboardInterrupt),
        atomic_dir(tmp_path / "out") as tmp,
        writer_threads(2) as pool,
    ):
        pool.submit(late_writer, tmp)
    assert done.is_set()  # the writer had ended before the cleanup
    assert hidden(tmp_path) == []
    assert not (tmp_path / "out").exists()


def test_an_output_created_meanwhile_is_not_replaced(tmp_path: Path) -> None:
    out = tmp_path / "out"
    appeared = pytest.raises(OutputExistsError, match="appeared while this command ran")
    with appeared, atomic_dir(out) as tmp:
        (tmp / "mine").write_text("x")
        out.mkdir()  # e.g. another program, not holding the lock
    assert list(out.iterdir()) == []
    assert hidden(tmp_path) == []


def test_stale_temp_folders_are_removed_and_not_datasets(
    small: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    """What a killed writer leaves (`.dataset=a.XXXXXXXX.tmp/`) is removed by the next
    writer of that output, and `map FLEET` never takes it for a dataset."""
    logs = _fleet(small, tmp_path)
    fleet = tmp_path / "fleet"
    stale = fleet / ".dataset=a.k3j4h5g6.tmp"
    stale.mkdir(parents=True)
    (stale / "scans.parquet").write_bytes(b"PAR1 half written")
    (fleet / ".dataset=a.old-12345").mkdir()
    other = fleet / ".dataset=abc.zzzzzzzz.tmp"  # another output's: not touched
    other.mkdir()
    code, _, err = cli("map", fleet, "--out", tmp_path / "runs0", "-q")
    assert code == 1 and "no dataset found" in err  # the hidden temp is no dataset
    assert cli("import", "carmen", logs, "--each", "--out", fleet, "-q")[0] == 0
    assert not stale.exists() and not (fleet / ".dataset=a.old-12345").exists()
    assert other.exists()
    other.rmdir()
    assert hidden(fleet) == []
    code, _, err = cli("map", fleet, "--out", tmp_path / "runs", "--method", "odometry", "-q")
    assert code == 0, err


def test_label_writes_the_run_as_a_whole(
    small: dict[str, Path], tmp_path: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Interrupted after labels.parquet and model.json are written: the run is as it was,
    and the re-run is not refused."""
    from toolkit.features import run as label_run

    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.json").write_text("{}")  # a map's output, say
    before = digest([run])

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr("toolkit.features.figures.membership_figure", interrupted)
    code, _, err = cli("label", small["dataset"], "--regions", small["regions"], "--out", run)
    assert code == 130 and "no output written" in err
    assert digest([run]) == before and hidden(tmp_path) == []
    monkeypatch.undo()
    code, _, err = cli("label", small["dataset"], "--regions", small["regions"], "--out", run)
    assert code == 0, err
    assert {"labels.parquet", "model.json", "metrics.json"} <= {p.name for p in run.iterdir()}
    assert (run / "metrics.json").read_text() == "{}"
    assert label_run.OUTPUTS


# ---------------------------------------------------------------- item 6: errors


def test_disk_full_names_the_users_path(
    small: dict[str, Path], tmp_path: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    import pyarrow.parquet as pq

    def full(*args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    # every Parquet table goes through it (write_table, ScansWriter, the streaming importers)
    monkeypatch.setattr(pq.ParquetWriter, "write_table", full)
    out = tmp_path / "ds"
    code, _, err = cli("import", "carmen", small["log"], "--out", out)
    assert code == 1
    assert (
        err.strip()
        == f"error: {out}: cannot write: no space left on the device; nothing was written"
    )
    assert list(tmp_path.iterdir()) == []


def test_read_only_output_names_the_users_path(
    small: dict[str, Path], tmp_path: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    import tempfile

    def refused(prefix: str = "", suffix: str = "", dir: str | None = None) -> str:
        raise PermissionError(errno.EACCES, "Permission denied", f"{dir}/{prefix}abcdefgh{suffix}")

    monkeypatch.setattr(tempfile, "mkdtemp", refused)
    out = tmp_path / "ro" / "ds"
    code, _, err = cli("import", "carmen", small["log"], "--out", out)
    assert code == 1
    assert err.strip() == f"error: {out}: cannot write: permission denied; nothing was written"


def test_corrupt_scans_parquet_is_one_line(
    small: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    ds = tmp_path / "ds"
    shutil.copytree(small["dataset"], ds)
    data = (ds / "scans.parquet").read_bytes()
    (ds / "scans.parquet").write_bytes(data[: len(data) // 2])
    for args in (("info", ds), ("map", ds, "--out", tmp_path / "run")):
        code, _, err = cli(*args)
        assert code == 1
        assert err.startswith(f"error: {ds / 'scans.parquet'}: damaged or not a dataset's file")
        assert "internal error" not in err and len(err.strip().splitlines()) == 1


def test_png_as_regions_is_one_line(small: dict[str, Path], tmp_path: Path, cli: Cli) -> None:
    png = tmp_path / "regions.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    code, _, err = cli("label", small["dataset"], "--regions", png, "--out", tmp_path / "run")
    assert code == 1
    assert err.strip() == f"error: {png}: not a text CSV (byte 0x89 at offset 0: an image?)"


@pytest.mark.parametrize("bogus", ["bogus", "tcp://", "local:x", "local:0", "http//x:1"])
def test_bogus_scheduler_is_one_line(
    small: dict[str, Path], tmp_path: Path, cli: Cli, bogus: str
) -> None:
    code, _, err = cli("map", small["dataset"], "--out", tmp_path / "run", "--scheduler", bogus)
    assert code == 1
    assert err.startswith(f"error: --scheduler {bogus!r}") and len(err.strip().splitlines()) == 1


# ---------------------------------------------------------------- item 5: --trajectory


def test_a_trajectory_that_does_not_cover_the_scans_is_an_error(
    small: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    t = pd.read_parquet(small["dataset"] / "scans.parquet", columns=["t"])["t"].to_numpy()
    span = t[-1] - t[0]
    short = tmp_path / "short.parquet"
    part = t[t < t[0] + 0.65 * span]  # covers 0-65 % of the log, like 0-261 s of 398 s
    pd.DataFrame({"t": part, "x": 0.0, "y": 0.0, "theta": 0.0}).to_parquet(short)
    code, _, err = cli("label", small["dataset"], "--regions", small["regions"],
                       "--trajectory", short, "--out", tmp_path / "run")  # fmt: skip
    assert code == 1
    assert f"error: {short}: trajectory covers" in err and "scans outside" in err
    full = tmp_path / "full.parquet"
    pd.DataFrame({"t": t - 0.5, "x": np.arange(len(t)) * 0.1, "y": 0.0, "theta": 0.0}).to_parquet(
        full
    )
    code, _, err = cli("label", small["dataset"], "--regions", small["regions"],
                       "--trajectory", full, "--out", tmp_path / "run")  # fmt: skip
    assert code == 0, err  # within the tolerance
    bad = tmp_path / "nan.parquet"
    pd.DataFrame({"t": t, "x": np.nan, "y": 0.0, "theta": 0.0}).to_parquet(bad)
    code, _, err = cli("label", small["dataset"], "--regions", small["regions"],
                       "--trajectory", bad, "--out", tmp_path / "run2")  # fmt: skip
    assert code == 1 and "non-finite pose" in err


# ---------------------------------------------------------------- item 4: 127.0.0.1


@pytest.mark.slow
def test_local_cluster_binds_only_loopback() -> None:
    """Scheduler, workers and the dashboard of `--scheduler local:N` listen on 127.0.0.1."""
    from toolkit.app.fleet import client_for

    with client_for("local:1") as client:
        assert client is not None
        info = client.scheduler_info()
        assert info["address"].startswith("tcp://127.0.0.1:")
        assert all(w.startswith("tcp://127.0.0.1:") for w in info["workers"])
        http = client.cluster.scheduler.http_server  # type: ignore[union-attr]
        hosts = {sock.getsockname()[0] for sock in http._sockets.values()}
        assert hosts == {"127.0.0.1"}, hosts


def test_meta_of_a_fleet_dataset_is_the_toolkits(small: dict[str, Path]) -> None:
    from toolkit.app.fleet import is_toolkit_dataset, is_toolkit_run

    assert is_toolkit_dataset(small["dataset"])
    assert not is_toolkit_run(small["dataset"])
    assert json.loads((small["dataset"] / "meta.json").read_text())["source"]["format"] == "carmen"
    assert not os.path.exists(small["dataset"] / ".lock")
