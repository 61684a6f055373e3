"""The bars of long commands count scans (simulate, map, label), advanced as the work goes."""

from __future__ import annotations

import importlib
import io
from pathlib import Path

import pytest
from rich.console import Console
from rich.progress import Progress, TaskID

import toolkit.progress
from tests.conftest import Cli
from toolkit import poses
from toolkit.mapping import MAP_STEPS

classify = importlib.import_module("toolkit.features.classify")  # the module, not the function

SCANS = 1500


class Recording(Progress):
    """A bar on a (fake) terminal that keeps every advance and files itself in `made` by its
    task's description."""

    def __init__(self, made: dict[str, Recording]) -> None:
        console = Console(file=io.StringIO(), force_terminal=True)
        super().__init__(console=console, redirect_stdout=False, redirect_stderr=False)
        self.made = made
        self.steps: list[float] = []

    def add_task(
        self,
        description: str,
        start: bool = True,
        total: float | None = 100.0,
        completed: int = 0,
        visible: bool = True,
        **fields: object,
    ) -> TaskID:
        self.made[description] = self
        return super().add_task(description, start, total, completed, visible, **fields)

    def advance(self, task_id: TaskID, advance: float = 1) -> None:
        self.steps.append(advance)
        super().advance(task_id, advance)


@pytest.fixture
def bars(monkeypatch: pytest.MonkeyPatch) -> dict[str, Recording]:
    """Progress forced on: every bar a command opens, by its task's description."""
    made: dict[str, Recording] = {}
    monkeypatch.setattr(toolkit.progress, "bar", lambda: Recording(made))
    monkeypatch.setattr(toolkit.progress, "enabled", lambda: True)  # as on a terminal
    return made


@pytest.fixture
def corridor(cli: Cli, tmp_path: Path, bars: dict[str, Recording]) -> Path:
    out = tmp_path / "corridor"
    code, _, err = cli("simulate", "corridor", "-f", "dataset", "--out", out, "--scans", SCANS)
    assert code == 0, err
    (task,) = bars.pop("simulate corridor").tasks
    assert task.total == SCANS and task.completed == SCANS  # poses ray-cast
    return out


def test_map_bar_counts_scan_pairs(
    cli: Cli,
    corridor: Path,
    tmp_path: Path,
    bars: dict[str, Recording],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(poses, "PAIRS_PER_STEP", 500)
    code, _, err = cli("map", corridor, "--out", tmp_path / "run")
    assert code == 0, err
    progress = bars["map (gaussian): scan pairs"]
    assert bars["map (gaussian): loops, outputs"] is progress
    pairs, steps = progress.tasks
    assert (pairs.total, steps.total) == (SCANS - 1, MAP_STEPS)
    assert progress.steps == [500, 500, 499] + [1] * MAP_STEPS  # per chunk of pairs, then outputs
    assert pairs.completed == pairs.total and steps.completed == steps.total


def test_label_bar_counts_scans(
    cli: Cli,
    corridor: Path,
    tmp_path: Path,
    bars: dict[str, Recording],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(classify, "SCANS_PER_STEP", 600)
    run = tmp_path / "run"
    code, _, err = cli("label", corridor, "--regions", corridor / "regions.csv", "--out", run)
    assert code == 0, err
    progress = bars["label: scans"]
    scans, steps = progress.tasks
    assert (scans.total, steps.total) == (SCANS, 2)  # every scan; the fitting, the outputs
    assert progress.steps == [1, 600, 600, 300, 1]
    assert scans.completed == scans.total and steps.completed == steps.total
    # applying a saved model: no fitting step
    code, _, err = cli("label", corridor, "--model", run / "model.json", "--out", tmp_path / "b")
    assert code == 0, err
    assert bars["label: outputs"].steps == [600, 600, 300, 1]


def test_bars_off_a_terminal_take_every_call_the_commands_make_without_rich(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Off a terminal `task` yields a silent bar (no rich `Progress` built): it takes what
    the importers, the simulator and the report call on a bar."""
    monkeypatch.setattr(toolkit.progress, "enabled", lambda: False)
    with toolkit.progress.task("import", total=10) as (bar, job):
        bar.advance(job, 3)
        bar.update(job, completed=7)
        bar.update(job, description="import: done")
    assert list(toolkit.progress.track(range(4), "items")) == [0, 1, 2, 3]
    with toolkit.progress.counted("map", 5, "pairs", "outputs", 2) as (count, step):
        count(5)
        step()
