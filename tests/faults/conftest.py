"""Shared inputs of the fault tests: small simulated logs in native formats and a dataset."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from tests.conftest import toolkit_process


def digest(paths: list[Path]) -> dict[str, str]:
    """sha256 of every file under `paths` (the inputs must be untouched by any fault)."""
    out = {}
    for root in paths:
        files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
        for f in files:
            out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def hidden(directory: Path) -> list[str]:
    """Temporary or lock entries (hidden names) anywhere below `directory`."""
    if not directory.exists():
        return []
    return sorted(str(p) for p in directory.rglob(".*"))


@pytest.fixture(scope="session")
def small(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A 300-scan simulated corridor: as a CARMEN log, as a dataset, and its regions CSV."""
    root = tmp_path_factory.mktemp("faults-small")
    log = root / "log"
    res = toolkit_process("simulate", "corridor", "--out", log, "--format", "carmen",
                          "--scans", 300, "--seed", 3)  # fmt: skip
    assert res.returncode == 0, res.stderr
    ds = root / "ds"
    res = toolkit_process("import", "carmen", log / "sim.log", "--out", ds, "-q")
    assert res.returncode == 0, res.stderr
    return {"log": log / "sim.log", "logdir": log, "dataset": ds, "regions": log / "regions.csv"}
