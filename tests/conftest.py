"""Shared fixtures. Real logs are read from ../shared/data/real (never copied here)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from toolkit.sim import Simulation, simulate

ROOT = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("TOOLKIT_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C works in the suite as in a terminal: a shell that starts it in the background
    (`make test &`, a script's `cmd &`) hands it SIGINT ignored, which the commands the tests
    start inherit, and the tests of what a stop does then see no stop (6 failed so, before)."""
    main = threading.current_thread() is threading.main_thread()
    if main and signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_report_header() -> str:
    """Which kernels OpenBLAS runs (the mapper's last bits follow them, and the seed-pinned
    real-log tests were written under SkylakeX's: `make test` asks for those where the CPU has
    AVX-512; docs/robustness.md, "Bits and machines")."""
    from threadpoolctl import threadpool_info

    kernels = sorted(
        {
            str(i.get("architecture"))
            for i in threadpool_info()
            if "openblas" in i.get("internal_api", "")
        }
    )
    pinned = os.environ.get(
        "OPENBLAS_CORETYPE", "not set (make test sets it where the CPU has AVX-512)"
    )
    return f"OpenBLAS kernels: {', '.join(kernels) or 'none loaded'}; OPENBLAS_CORETYPE {pinned}"


@pytest.fixture(scope="session")
def real() -> Path:
    """The folder of real logs; tests that need it (marked `real` by the hook below) are
    skipped when it is missing (a clone without ../shared; TOOLKIT_REAL_DATA=/elsewhere)."""
    if not REAL.is_dir():
        pytest.skip(f"real logs not found at {REAL} (set TOOLKIT_REAL_DATA)")
    return REAL


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark `real` every test that reaches the `real` fixture, directly or through other
    fixtures, so that `-m "not real"` leaves out all that read ../shared."""
    for item in items:
        if "real" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.real)


@pytest.fixture(scope="session")
def corridor_sim() -> Simulation:
    """The simulator's corridor, seed 0 (2000 scans), simulated once per session: read it,
    do not change it (`dataclasses.replace` for a variant)."""
    return simulate("corridor", seed=0)


@pytest.fixture(scope="session")
def building_sim() -> Simulation:
    """The simulator's building, seed 0 (4000 scans), simulated once per session; read only."""
    return simulate("building", seed=0)


@pytest.fixture(autouse=True)
def _no_progress(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TOOLKIT_NO_PROGRESS", "1")


Cli = Callable[..., tuple[int, str, str]]


@pytest.fixture
def cli(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> Cli:
    """Run `toolkit ARGS...` in this process through the real entry point.

    Returns (exit status, stdout, stderr); faster than a subprocess, same error handling.
    """
    from toolkit.app.cli import main

    def run(*args: object) -> tuple[int, str, str]:
        capsys.readouterr()
        monkeypatch.setattr(sys, "argv", ["toolkit", *map(str, args)])
        try:
            main()
            code = 0
        except SystemExit as e:
            code = int(e.code or 0)
        out, err = capsys.readouterr()
        return code, out, err

    return run


def toolkit_process(*args: object, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """Run `python -m toolkit ARGS...` in a new process: start-up and exit status as a user sees them."""
    return subprocess.run(
        [sys.executable, "-m", "toolkit", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
