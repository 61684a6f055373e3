"""`evaluate --paired`: the default against a variant on the same worlds, each measure's change
per world averaged with twice its standard error (how every place setting is judged)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest

from toolkit.features.evaluate import FULL, WorldKind, paired

ROOT = Path(__file__).resolve().parents[2]
#: a sparse world as the Intel lab's (brief rooms, crossings), where the view ahead acts
SPARSE = WorldKind(spacing=1.0, turn=0.5, entered=True, brief=True, crossings=True)


@pytest.mark.slow
def test_paired_tells_a_change_from_none(tmp_path: Path) -> None:
    same, worlds = paired(dataclasses.replace(FULL), (0,), **SPARSE)
    assert len(worlds) == 1 and set(same["run"]) == {"a", "b", "c"}
    assert (same["change"] == 0).all() and (same["equal"] == same["worlds"]).all()
    assert {"BA", "ECE", "corridor recall", "room recall"} <= set(same["measure"])

    # without the view ahead (session 29's part for sparse logs) the world scores otherwise
    out = tmp_path / "paired.md"
    done = subprocess.run(
        [sys.executable, "-m", "toolkit.features.evaluate", "--seeds", "0", "--spacing", "1",
         "--turn", "0.5", "--entered", "--brief", "--crossings",
         "--paired", '{"sparse_view_ahead": false}', "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert "paired per world, 1 worlds" in done.stdout and out.read_text() in done.stdout + "\n"
    per_world = json.loads(out.with_suffix(".json").read_text())
    assert per_world[0]["default"] == json.loads(json.dumps(worlds[0]["default"]))
    assert any(
        per_world[0]["variant"][run]["ba"] != per_world[0]["default"][run]["ba"] for run in "abc"
    )


def test_paired_refuses_an_unknown_setting() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "toolkit.features.evaluate", "--paired", '{"nope": 1}'],
        cwd=ROOT, capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 2 and "no Config field 'nope'" in done.stderr
    assert "Traceback" not in done.stderr
