"""What the generators share: the logs, and the runs on them, each made once per report.

Generators ask the context for a dataset, a trajectory by a method or the labels of a log;
the context imports, maps or labels on first use (with the toolkit's own functions) and
keeps the result, so Table 1, Fig. 6 and the accuracy table use the same runs, timed in
this report's run.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from reports.base import NotAvailable, require
from toolkit.dataset import Dataset

ROOT = Path(__file__).resolve().parents[1]
CORRIDOR = "corridor"
METHODS = ("odometry", "gaussian", "icp")


def default_real() -> Path | None:
    """The folder of real logs: $TOOLKIT_REAL_DATA, else ../shared/data/real beside the repo."""
    env = os.environ.get("TOOLKIT_REAL_DATA")
    candidates = [Path(env)] if env else [ROOT.parent / "shared" / "data" / "real"]
    return next((p for p in candidates if p.is_dir()), None)


@dataclass
class Source:
    """A log the report covers: where it is, where it came from, its training regions."""

    name: str
    path: Path | None
    origin: str  # "simulated", "command line", "bundled", "real"
    regions: Path | None = None
    note: str = ""


@dataclass
class Run:
    """A trajectory of one log by one method, timed in this run, with its accuracy."""

    dataset: str
    method: str
    trajectory: pd.DataFrame
    seconds: float
    metrics: dict[str, Any] = field(default_factory=dict)
    folder: str | None = None  # relative to the report, when the run's files are kept


@dataclass
class Context:
    """Shared state of one report run (see the module docstring)."""

    out: Path  # the report folder being written
    work: Path  # scratch space for imported logs (not part of the report)
    quick: bool = False
    seed: int = 0
    sources: dict[str, Source] = field(default_factory=dict)
    real: Path | None = None
    step: Callable[[str], None] = lambda _: None  # progress: called with what starts
    _datasets: dict[str, Dataset] = field(default_factory=dict)
    _cache: dict[Any, Any] = field(default_factory=dict)

    # ------------------------------------------------------------ logs

    def cached(self, key: Any, make: Callable[[], Any]) -> Any:
        """`make()` once per key; a NotAvailable is remembered too, and raised again."""
        if key not in self._cache:
            try:
                self._cache[key] = make()
            except NotAvailable as e:
                self._cache[key] = e
        value = self._cache[key]
        if isinstance(value, NotAvailable):
            raise value
        return value

    def corridor(self) -> Any:
        """The simulator's corridor (8 sections x 250 scans), with ground truth and labels."""

        def make() -> Any:
            sim_mod = require("toolkit.sim", "simulate")
            self.step("simulate the corridor")
            sim = sim_mod.simulate(CORRIDOR, seed=self.seed)
            self._datasets[CORRIDOR] = sim.dataset
            self.sources.setdefault(CORRIDOR, Source(CORRIDOR, None, "simulated"))
            return sim

        return self.cached(("sim", CORRIDOR), make)

    def dataset(self, name: str) -> Dataset:
        """A log by name, loaded once."""
        if name == CORRIDOR:
            self.corridor()
        if name not in self._datasets:
            source = self.sources.get(name)
            if source is None or source.path is None:
                raise NotAvailable(f"no log named {name!r}")
            from toolkit.dataset import load

            self._datasets[name] = load(source.path)
        return self._datasets[name]

    def real_log(self, name: str, fmt: str, relpath: str, **options: str) -> str:
        """Import a real log from the real-data folder once; its name for `dataset()`."""

        def make() -> str:
            if self.real is None:
                raise NotAvailable("the real logs folder is not here (set TOOLKIT_REAL_DATA)")
            source = self.real / relpath
            if not source.exists():
                raise NotAvailable(f"{source} is missing")
            importers = require("importers", "import_log", "ImportOptions")
            try:
                importers.get(fmt) if fmt != "auto" else None
            except Exception as e:  # the format's importer is not merged yet
                raise NotAvailable(f"the {fmt} importer: {e}") from None
            self.step(f"import {relpath}")
            target = self.work / "datasets" / name
            importers.import_log(
                fmt, [source], target, importers.ImportOptions(extra=dict(options)), force=True
            )
            self.sources[name] = Source(name, target, "real", note=relpath)
            return name

        return self.cached(("real", name), make)

    # ------------------------------------------------------------ runs

    def run(self, name: str, method: str) -> Run:
        """The trajectory of log `name` by `method`, computed once and timed."""
        return self.cached(("run", name, method), lambda: self._run(name, method))

    def _run(self, name: str, method: str) -> Run:
        from reports import runs

        ds = self.dataset(name)
        self.step(f"map {name} ({method})")
        return runs.map_run(self, name, ds, method)

    def labels(self, name: str) -> Any:
        """Labels of log `name` from its training regions, computed once."""
        from reports import runs

        def make() -> Any:
            ds = self.dataset(name)
            self.step(f"label {name}")
            return runs.label_run(self, name, ds)

        return self.cached(("labels", name), make)

    def logs(self, origin: str | None = None) -> list[str]:
        return [n for n, s in self.sources.items() if origin is None or s.origin == origin]

    @contextmanager
    def part(self, section: Any, what: str) -> Iterator[None]:
        """Run one part of a section; a missing piece marks only that part not available."""
        try:
            yield
        except NotAvailable as e:
            section.unavailable.append(f"{what}: {e}")
