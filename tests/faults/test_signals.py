"""Fault injection: `toolkit` killed by SIGINT, SIGTERM or SIGKILL at several points of
import, map, label, report and the fleet paths (with and without Dask). Afterwards the output is
complete and valid or absent, the inputs are untouched, a re-run succeeds and leaves no
temporary folder. The points: early (during start-up imports), while the output's temporary
directory exists (writing), and after a delay."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import psutil
import pytest

from tests.faults.conftest import digest, hidden
from toolkit.dataset import is_dataset_dir

ENV = {**os.environ, "TOOLKIT_NO_PROGRESS": "1"}


def _writing(parent: Path) -> bool:
    """A toolkit temporary directory exists somewhere below `parent`."""
    return parent.exists() and any(p.name.endswith(".tmp") for p in parent.rglob(".*"))


def _maps(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return ""


def kill_at(args: list[object], sig: int, when: str, parent: Path) -> tuple[int, str]:
    """Run `toolkit ARGS`, send `sig` at `when` (early | writing | late); (status, stderr)."""
    proc = subprocess.Popen([sys.executable, "-m", "toolkit", *map(str, args)], env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    start = time.monotonic()
    if when == "early":  # while numpy loads: the handlers are installed, nothing is written
        while proc.poll() is None and "numpy/" not in _maps(proc.pid):
            assert time.monotonic() - start < 120
            time.sleep(0.001)
    elif when == "late":
        time.sleep(4.0)
    else:
        while proc.poll() is None and not _writing(parent) and time.monotonic() - start < 240:
            time.sleep(0.005)
    if proc.poll() is None:
        proc.send_signal(sig)
    _, err = proc.communicate(timeout=240)
    return proc.returncode, err


def rerun(args: list[object]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "toolkit", *map(str, args), "--force"],
                          env=ENV, capture_output=True, text=True, timeout=600)  # fmt: skip


def check_stopped(code: int, err: str, sig: int, when: str) -> None:
    """How a stopped command ends: 128+N and one line (0: it finished first; -9: SIGKILL).
    Late, the signal may also meet the interpreter's shutdown, after the command's work,
    when Python has restored the default handlers: then it dies of it (-N), silently."""
    if sig == signal.SIGKILL:
        assert code in (0, -9), err
        return
    assert code in ((0, 128 + sig, -sig) if when == "late" else (0, 128 + sig)), err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    if code == 128 + sig:
        assert err.strip().splitlines()[-1].startswith("interrupted ("), err


def valid_dataset(path: Path) -> None:
    import toolkit

    assert toolkit.load(path).n_scans > 0


def valid_run(path: Path) -> None:
    metrics = json.loads((path / "metrics.json").read_text())
    assert metrics["scans"] > 0
    assert (path / "trajectory.parquet").is_file() and (path / "cloud.ply").stat().st_size > 0


def valid_label(path: Path) -> None:
    import pandas as pd

    names = {p.name for p in path.iterdir()} if path.exists() else set()
    if "labels.parquet" in names or "model.json" in names:  # all of them, or none
        assert {"labels.parquet", "model.json", "labels-metrics.json"} <= names
        assert len(pd.read_parquet(path / "labels.parquet")) > 0


def fault(
    args: list[object],
    out: Path,
    inputs: list[Path],
    sig: int,
    when: str,
    valid: Callable[[Path], None],
    outputs: Callable[[Path], list[Path]] = lambda out: [out],
) -> None:
    before = digest(inputs)
    code, err = kill_at(args, sig, when, out.parent)
    check_stopped(code, err, sig, when)
    for o in outputs(out):  # complete and valid, or absent
        if o.exists():
            valid(o)
    if sig != signal.SIGKILL:
        assert hidden(out.parent) == [], err  # the clean path removed its temporaries
    assert digest(inputs) == before
    res = rerun(args)
    assert res.returncode == 0, res.stderr
    for o in outputs(out):
        valid(o)
    assert hidden(out.parent) == [], res.stderr  # stale temporaries of a SIGKILL: gone
    assert digest(inputs) == before


SIGNALS = [signal.SIGINT, signal.SIGTERM, signal.SIGKILL]
FAST = [(signal.SIGINT, "writing"), (signal.SIGTERM, "writing"), (signal.SIGKILL, "writing")]
ALL = [(s, w) for s in SIGNALS for w in ("early", "writing", "late")]


def _cases(fast: Sequence[tuple[int, str]]) -> list[object]:
    return [
        pytest.param(s, w, id=f"{signal.Signals(s).name}-{w}")
        if (s, w) in fast
        else pytest.param(s, w, id=f"{signal.Signals(s).name}-{w}", marks=pytest.mark.slow)
        for s, w in ALL
    ]


@pytest.mark.parametrize(("sig", "when"), _cases(FAST))
def test_import(small: dict[str, Path], tmp_path: Path, sig: int, when: str) -> None:
    out = tmp_path / "w" / "ds"
    fault(["import", "carmen", small["log"], "--out", out], out, [small["logdir"]], sig, when,
          valid_dataset)  # fmt: skip


@pytest.mark.parametrize(("sig", "when"), _cases([(signal.SIGTERM, "writing")]))
def test_map(small: dict[str, Path], tmp_path: Path, sig: int, when: str) -> None:
    out = tmp_path / "w" / "run"
    fault(["map", small["dataset"], "--out", out], out, [small["dataset"]], sig, when, valid_run)


@pytest.mark.parametrize(("sig", "when"), _cases([(signal.SIGTERM, "writing")]))
def test_label(small: dict[str, Path], tmp_path: Path, sig: int, when: str) -> None:
    out = tmp_path / "w" / "run"
    out.mkdir(parents=True)
    (out / "metrics.json").write_text("{}")
    args = ["label", small["dataset"], "--regions", small["regions"], "--out", out]
    fault(args, out, [small["dataset"], small["regions"]], sig, when, valid_label)
    assert (out / "metrics.json").read_text() == "{}"


def valid_report(path: Path) -> None:
    assert (path / "index.html").stat().st_size > 0
    assert json.loads((path / "report.json").read_text())


@pytest.mark.slow  # a report and its re-run take ~2 min: one case, the others are import's
@pytest.mark.parametrize(("sig", "when"), [(signal.SIGTERM, "writing")], ids=["SIGTERM-writing"])
def test_report(small: dict[str, Path], tmp_path: Path, sig: int, when: str) -> None:
    out = tmp_path / "w" / "report"
    args = ["report", small["dataset"], "--regions", small["regions"], "--out", out,
            "--no-real", "--quick"]  # fmt: skip
    fault(args, out, [small["dataset"], small["regions"]], sig, when, valid_report)


def _fleet_outputs(out: Path) -> list[Path]:
    return sorted(p for p in out.glob("dataset=*")) if out.exists() else []


def _logs(small: dict[str, Path], tmp_path: Path, n: int = 3) -> Path:
    logs = tmp_path / "logs"
    logs.mkdir()
    for i in range(n):
        (logs / f"r{i}.log").write_bytes(small["log"].read_bytes())
    return logs


@pytest.mark.parametrize(("sig", "when"), _cases([(signal.SIGKILL, "writing")]))
def test_fleet_import(small: dict[str, Path], tmp_path: Path, sig: int, when: str) -> None:
    logs = _logs(small, tmp_path)
    out = tmp_path / "w" / "fleet"
    fault(["import", "carmen", logs, "--each", "--out", out], out, [logs], sig, when,
          valid_dataset, _fleet_outputs)  # fmt: skip
    assert len(_fleet_outputs(out)) == 3


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL])
def test_fleet_on_dask(small: dict[str, Path], tmp_path: Path, sig: int) -> None:
    """The issue's case: `--scheduler local:2`, stopped while the workers write. The nanny
    kills its worker before the worker's cleanup: the next run removes what it left."""
    logs = _logs(small, tmp_path)
    out = tmp_path / "w" / "fleet"
    args = ["import", "carmen", logs, "--each", "--out", out, "--scheduler", "local:2"]
    before = digest([logs])
    code, err = kill_at(args, sig, "writing", out.parent)
    assert code in (0, -9, 128 + sig), err
    assert "Traceback" not in err.split("interrupted")[-1]
    for o in _fleet_outputs(out):
        if o.exists():
            valid_dataset(o)
    res = rerun(args)
    assert res.returncode == 0, res.stderr
    assert len(_fleet_outputs(out)) == 3 and hidden(out.parent) == []
    assert digest([logs]) == before
    maps = tmp_path / "w" / "runs"
    res = subprocess.run([sys.executable, "-m", "toolkit", "map", out, "--out", maps, "--method",
                          "odometry", "--scheduler", "local:2", "-q"], env=ENV,
                         capture_output=True, text=True, timeout=600)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in maps.iterdir()) == [p.name for p in _fleet_outputs(out)]


def _workers(pid: int) -> list[int]:
    """The Dask worker processes `pid` started (spawned by multiprocessing)."""

    def worker(child: psutil.Process) -> bool:
        try:
            return "--multiprocessing-fork" in child.cmdline()
        except psutil.Error:  # gone meanwhile
            return False

    return sorted(c.pid for c in psutil.Process(pid).children() if worker(c))


def _alive(pid: int) -> bool:
    """Running (a zombie nobody reaped yet is dead)."""
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _pipes(pid: int, write: bool) -> dict[str, int]:
    """{"pipe:[inode]": fd} of the pipe ends `pid` holds open for writing (or reading)."""
    ends = {}
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
            info = (Path(f"/proc/{pid}/fdinfo") / fd.name).read_text()
            flags = int(info.split("flags:")[1].split()[0], 8)
        except (OSError, IndexError, ValueError):
            continue
        if target.startswith("pipe:") and (flags & os.O_ACCMODE == os.O_WRONLY) == write:
            ends[target] = int(fd.name)
    return ends


@pytest.mark.skipif(sys.platform != "linux", reason="the kernel's parent-death signal")
def test_local_cluster_workers_are_killed_with_their_parent() -> None:
    """Every worker of `client_for`'s LocalCluster (both fleet paths take it) has asked the
    kernel for SIGKILL when the command dies."""
    from toolkit.app.fleet import client_for
    from toolkit.app.fleet_worker import parent_death_signal

    with client_for("local:2") as client:
        assert client is not None
        signals = client.run(parent_death_signal)
    assert list(signals.values()) == [signal.SIGKILL] * 2, signals


@pytest.mark.slow
@pytest.mark.skipif(sys.platform != "linux", reason="/proc; the kernel's parent-death signal")
def test_no_dask_worker_outlives_a_killed_command(small: dict[str, Path], tmp_path: Path) -> None:
    """SIGKILL to `import --each --scheduler local:2` whose scheduler had stopped answering
    (a loaded machine; here SIGSTOP for 2 s, past the workers' heartbeat interval) left each
    worker's heartbeat unanswered: when the command died, the workers printed "Failed to
    communicate with scheduler during heartbeat" and a traceback onto its stderr, unless
    Dask's guard (a thread that ends the worker when a pipe from its parent closes) came
    first. The test keeps those pipes open itself, as load delays the guard, so the race is
    lost every time: without the kernel's parent-death signal (`toolkit.app.fleet_worker`)
    both workers print it and are still alive 3 s after the command died."""
    logs = _logs(small, tmp_path)
    out = tmp_path / "w" / "fleet"
    args = ["import", "carmen", logs, "--each", "--out", out, "--scheduler", "local:2"]
    proc = subprocess.Popen([sys.executable, "-m", "toolkit", *map(str, args)], env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    held: list[int] = []
    workers: list[int] = []
    try:
        start = time.monotonic()
        while proc.poll() is None and not _writing(out.parent):
            assert time.monotonic() - start < 120
            time.sleep(0.005)
        proc.send_signal(signal.SIGSTOP)  # the scheduler stops answering
        workers = _workers(proc.pid)
        assert len(workers) == 2, workers  # started: the cluster waits for its workers
        stderr = os.readlink(f"/proc/{proc.pid}/fd/2")
        read = set().union(*(_pipes(w, write=False) for w in workers))
        held = [os.open(f"/proc/{proc.pid}/fd/{fd}", os.O_WRONLY)
                for pipe, fd in _pipes(proc.pid, write=True).items()
                if pipe in read and pipe != stderr]  # fmt: skip
        assert held  # Dask's guard pipes (and the nannies' queues): no EOF when it dies
        time.sleep(2.0)  # each worker's heartbeat is sent and waits for its answer
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
        time.sleep(3.0)  # past the heartbeat: an orphan would have printed by now
        left = [w for w in workers if _alive(w)]
    finally:
        for fd in held:
            os.close(fd)
        for w in workers:  # what the test started: no orphan left, whatever failed
            if _alive(w):
                os.kill(w, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert left == [], err  # none outlived the command
    assert "Traceback" not in err and " - distributed." not in err, err


@pytest.mark.parametrize("library", ["numpy/", "pandas/_libs", "pyarrow/"])
def test_ctrl_c_during_start_up_is_one_line(small: dict[str, Path], library: str) -> None:
    """Ctrl-C while the command is still loading its libraries (the moment `library` is
    mapped into the process: numpy, pandas, pyarrow are being imported): one line, 130."""
    proc = subprocess.Popen([sys.executable, "-m", "toolkit", "info", small["dataset"]], env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    start = time.monotonic()
    while proc.poll() is None and library not in _maps(proc.pid):
        assert time.monotonic() - start < 60
        time.sleep(0.001)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode in (0, 130), err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err


def test_sigterm_takes_the_clean_path(tmp_path: Path) -> None:
    """SIGTERM (batch schedulers, `timeout`, container stops) removes the temporary
    directory like Ctrl-C does, and says so (status 143)."""
    out = tmp_path / "sim"
    code, err = kill_at(["simulate", "building", "--out", out, "--format", "dataset",
                         "--scans", 200000], signal.SIGTERM, "late", tmp_path)  # fmt: skip
    assert code == 143, err
    assert err.strip().splitlines()[-1] == "interrupted (SIGTERM); no output written"
    assert list(tmp_path.iterdir()) == []


def test_an_unfinished_write_is_never_a_dataset(tmp_path: Path) -> None:
    temp = tmp_path / ".ds.abcdefgh.tmp"
    temp.mkdir()
    (temp / "meta.json").write_text("{}")
    (temp / "scans.parquet").write_bytes(b"PAR1")
    assert not is_dataset_dir(temp)  # it looks like one, but a killed writer left it
    from toolkit.app.fleet import find_datasets

    assert find_datasets([tmp_path]) == []


def test_a_stop_wrapped_by_an_import_is_still_a_stop(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """SIGTERM landing in an extension module's initialisation comes out as ImportError
    ("initialization failed", seen in CI on a cold clone): still 143 and the one line."""
    import toolkit.app.cli as cli
    from toolkit.app import signals

    def stopped_inside_an_import(**_: object) -> None:
        signals.received = signal.SIGTERM  # as the handler records it, before raising
        raise ImportError("initialization failed")

    monkeypatch.setattr(signals, "received", None)
    monkeypatch.setattr(cli, "app", stopped_inside_an_import)
    with pytest.raises(SystemExit) as stop:
        cli.main()
    assert stop.value.code == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip() == "interrupted (SIGTERM); no output written"


def _python(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], env=ENV, capture_output=True,
                          text=True, timeout=120)  # fmt: skip


def test_a_stop_swallowed_by_a_callback_from_c_still_stops() -> None:
    """Ctrl-C landing in a callback from C (llvmlite's object cache while numba compiles, on
    a cold start) cannot propagate there: Python printed "Exception ignored" and the command
    ran on to the end. The stop is raised again where Python code runs next."""
    res = _python(
        "import ctypes, signal, time\n"
        "from toolkit.app import signals\n"
        "signals.install()\n"
        "callback = ctypes.CFUNCTYPE(None)(lambda: signal.raise_signal(signal.SIGINT))\n"
        "try:\n"
        "    callback()\n"
        "    for _ in range(500):\n"
        "        time.sleep(0.01)\n"
        "    print('ran on')\n"
        "except KeyboardInterrupt:\n"
        "    print('stopped')\n"
    )
    assert res.stdout.strip() == "stopped", res.stdout + res.stderr
    assert "Exception ignored" not in res.stderr, res.stderr


def test_a_stop_that_broke_an_import_keeps_its_status_whatever_the_teardown() -> None:
    """A stop inside open3d's initialisation (ImportError "initialization failed") left a
    half-made extension whose teardown at exit turned 143 into status 1 (a cold clone under
    load); the process now ends after the exit handlers, without that teardown. A teardown
    that fails stands in for the broken extension."""
    res = _python(
        "import os, signal, sys\n"
        "import toolkit.app.cli as cli\n"
        "from toolkit.app import entry, signals\n"
        "class Extension:\n"
        "    def __del__(self):\n"
        "        os._exit(1)\n"
        "sys.modules['half_made'] = Extension()  # torn down with the modules\n"
        "def app(**_):\n"
        "    signals.received = signal.SIGTERM\n"
        "    raise ImportError('initialization failed')\n"
        "cli.app = app\n"
        "entry.main()\n"
    )
    assert res.returncode == 128 + signal.SIGTERM, res.stderr
    assert res.stderr.strip() == "interrupted (SIGTERM); no output written"
