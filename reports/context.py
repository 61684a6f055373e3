"""What the generators share: the logs, and the runs on them, each made once per report.

Generators ask the context for a dataset, a trajectory by a method or the labels of a log;
the context imports, maps or labels on first use (with the toolkit's own functions) and
keeps the result, so Table 1, Fig. 6 and the accuracy table use the same runs, timed in
this report's run.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar, cast

import numpy as np
import pandas as pd

import importers
from reports.base import NotAvailable
from reports.runs import Labelled, Run, label_log, map_log, slice_scans
from toolkit.dataset import Dataset, load
from toolkit.errors import ToolkitError
from toolkit.poses import with_drift
from toolkit.sim import Simulation, simulate

if TYPE_CHECKING:
    from reports.base import Section
    from toolkit.sim import Simulation

T = TypeVar("T")

ROOT = Path(__file__).resolve().parents[1]
CORRIDOR = "corridor"
MATCHERS = ("gaussian", "icp", "icp-point")  # scan matchers: ours, ICP point-to-line, Open3D
QUICK_MATCHERS = ("gaussian", "icp")
QUICK_CORRIDOR_SCANS = 400  # quick mode: the same corridor in 8 sections of 50 scans
QUICK_BUNDLED_SCANS = 1000  # quick mode: only the bundled logs this short
QUICK_REAL_SCANS = 300  # quick mode: the real logs mapped by every method are cut to this
CATALOG = ROOT / "datasets" / "catalog.json"  # the bundled simulated logs
REAL_REGIONS = ROOT / "datasets" / "real-regions"  # training regions for the real logs


# real logs the paper's figures use: name -> (format, path under the real folder, options)
REAL_LOGS: dict[str, tuple[str, str, dict[str, str]]] = {
    "dpslam_loop5": ("auto", "dpslam_loop5/loop5.log", {}),
    "intel": ("carmen", "carmen_radish_corrected/intel-corrected.log.gz", {"poses": "groundtruth"}),
}
INTEL_DRIFT = "intel+drift"
QUICK_CUT = ("dpslam_loop5",)  # and INTEL_DRIFT (cut as it is made); Intel is labelled whole
RESERVED = {CORRIDOR, INTEL_DRIFT, *REAL_LOGS}  # names a dataset given by path does not take


def default_real() -> Path | None:
    """The folder of real logs: $TOOLKIT_REAL_DATA, else ../shared/data/real beside the repo."""
    env = os.environ.get("TOOLKIT_REAL_DATA")
    candidates = [Path(env)] if env else [ROOT.parent / "shared" / "data" / "real"]
    return next((p for p in candidates if p.is_dir()), None)


@dataclass
class Source:
    """A log the report covers: where it is, where it came from, its training regions."""

    name: str
    path: Path | None  # the dataset folder (None until imported, or made in memory)
    origin: str  # "simulated", "command line", "bundled", "real"
    regions: Path | None = None
    note: str = ""
    truth: Path | None = None  # the simulator's truth.parquet (true label per scan)
    native: tuple[str, list[Path]] | None = None  # (format, sources) to import from


def with_truth_poses(ds: Dataset, source: Source) -> Dataset:
    """A simulated log whose native format carries no ground truth (ARIA keeps robotGlobal as
    a pose stream, a laser capture has no poses) gets it from the simulator's truth.parquet."""
    if ds.groundtruth is not None or source.truth is None or not source.truth.is_file():
        return ds
    truth = pd.read_parquet(source.truth)
    if not {"t", "x", "y", "theta"} <= set(truth.columns):
        return ds
    source.note += " [ground truth: the simulator's truth.parquet]"
    return replace(ds, groundtruth=truth[["t", "x", "y", "theta"]])


def catalog_sources(catalog: Path = CATALOG, max_scans: int | None = None) -> dict[str, Source]:
    """The bundled logs named by datasets/catalog.json (imported when first used); with
    `max_scans`, only those the catalog says are no longer."""
    if not catalog.is_file():
        return {}
    try:
        samples = json.loads(catalog.read_text()).get("samples", [])
    except (OSError, json.JSONDecodeError) as e:
        raise ToolkitError(f"cannot read the catalog: {e}", file=catalog) from None
    sources = {}
    for sample in samples:
        if max_scans is not None and int(sample.get("scans") or 0) > max_scans:
            continue
        folder = catalog.parent / sample["path"]
        fmt = sample["format"]
        files = [folder / f for f in sample.get("files", [])]
        native = [folder] if fmt == "rawseeds" else files[:1]  # a session is its folder

        regions, truth = (sample.get(k) for k in ("regions", "truth"))
        name = sample["name"]
        sources[name] = Source(
            name,
            None,
            "bundled",
            regions=catalog.parent / regions if regions else None,
            note=sample.get("summary", ""),
            truth=catalog.parent / truth if truth else None,
            native=(fmt, native),
        )
    return sources


@dataclass
class Context:
    """Shared state of one report run (see the module docstring)."""

    out: Path  # the report folder being written
    work: Path  # scratch space for imported logs (not part of the report)
    quick: bool = False
    seed: int = 0
    sources: dict[str, Source] = field(default_factory=dict)
    real_dir: Path | None = None
    step: Callable[[str], None] = lambda _: None  # progress: called with what starts
    load_at_start: tuple[float, float, float] = field(default_factory=os.getloadavg)
    _datasets: dict[str, Dataset] = field(default_factory=dict)
    _cache: dict[Any, Any] = field(default_factory=dict)

    @property
    def matchers(self) -> tuple[str, ...]:
        """The scan matchers compared (quick mode leaves out the slow Open3D ICP)."""
        return QUICK_MATCHERS if self.quick else MATCHERS

    def methods(self, name: str) -> tuple[str, ...]:
        """The trajectories drawn for log `name`: odometry alone (when it has odometry), then
        every scan matcher."""
        odometry = ("odometry",) if self.dataset(name).odometry is not None else ()
        return (*odometry, *self.matchers)

    # ------------------------------------------------------------ logs

    def cached(self, key: Hashable, make: Callable[[], T]) -> T:
        """`make()` once per key; a NotAvailable is remembered too, and raised again."""
        if key not in self._cache:
            try:
                self._cache[key] = make()
            except NotAvailable as e:
                self._cache[key] = e
        value = self._cache[key]
        if isinstance(value, NotAvailable):
            raise value
        return cast(T, value)

    def corridor(self) -> Simulation:
        """The simulator's corridor (8 sections x 250 scans), with ground truth and labels."""

        def make() -> Simulation:
            self.step("simulate the corridor")
            extra = {"scans": QUICK_CORRIDOR_SCANS} if self.quick else {}
            sim = simulate(CORRIDOR, seed=self.seed, **extra)
            self._datasets[CORRIDOR] = sim.dataset
            self.sources.setdefault(
                CORRIDOR, Source(CORRIDOR, None, "simulated", note="the paper's corridor")
            )
            return sim

        return self.cached(("sim", CORRIDOR), make)

    def loaded(self, name: str) -> Dataset | None:
        """The log if it has been loaded already (no import, no simulation)."""
        return self._datasets.get(name)

    def dataset(self, name: str) -> Dataset:
        """A log by name, loaded once."""
        if name not in self._datasets:
            if name == CORRIDOR:
                self.corridor()
            elif name == INTEL_DRIFT:
                self.drifted(INTEL_DRIFT, "intel")
            elif name in REAL_LOGS:
                self.real_named(name)
        if name not in self._datasets:
            source = self.sources.get(name)
            if source is not None and source.path is None and source.native is not None:
                self._import_native(source)
            if source is None or source.path is None:
                raise NotAvailable(f"no log named {name!r}")
            ds = with_truth_poses(load(source.path), source)
            if name in QUICK_CUT:
                ds, note = self._quick_cut(ds)
                source.note += note
            self._datasets[name] = ds
        return self._datasets[name]

    def _quick_cut(self, ds: Dataset) -> tuple[Dataset, str]:
        """Quick mode maps only the first scans of the real logs it maps by every method."""
        if not self.quick or ds.n_scans <= QUICK_REAL_SCANS:
            return ds, ""
        cut = slice_scans(ds, np.arange(QUICK_REAL_SCANS))
        return cut, f", first {QUICK_REAL_SCANS} scans (quick mode)"

    def _import_native(self, source: Source) -> None:
        """Import a bundled log into the scratch space; a failure says why, for this log."""

        def make() -> Path:
            assert source.native is not None
            fmt, paths = source.native
            self.step(f"import {source.name}")
            target = self.work / "datasets" / source.name
            try:
                importers.import_log(fmt, paths, target, force=True)
            except ToolkitError as e:
                raise NotAvailable(f"importing {source.name} failed: {e.line()}") from None
            return target

        source.path = self.cached(("import", source.name), make)

    def real_log(self, name: str, fmt: str, relpath: str, **options: str) -> str:
        """Import a real log from the real-data folder once; its name for `dataset()`."""

        def make() -> str:
            if self.real_dir is None:
                raise NotAvailable("the real logs folder is not here (set TOOLKIT_REAL_DATA)")
            source = self.real_dir / relpath
            if not source.exists():
                raise NotAvailable(f"{source} is missing")
            self.step(f"import {relpath}")
            target = self.work / "datasets" / name
            importers.import_log(
                fmt, [source], target, importers.ImportOptions(extra=dict(options)), force=True
            )
            regions = REAL_REGIONS / f"{name}-regions.csv"
            self.sources[name] = Source(
                name, target, "real", regions if regions.is_file() else None, note=relpath
            )
            return name

        return self.cached(("real", name), make)

    def drifted(self, name: str, base: str) -> str:
        """Log `base` with its odometry replaced by drifting wheel odometry simulated along its
        ground truth (`toolkit.poses.with_drift`: the same default drift as the tests and the
        bench), registered as `name`."""

        def make() -> str:
            ds, note = self._quick_cut(self.dataset(base))
            if ds.groundtruth is None:
                raise NotAvailable(f"{base} has no ground truth to add drift to")
            self._datasets[name] = with_drift(ds, self.seed)
            origin = self.sources[base]
            self.sources[name] = Source(
                name, None, origin.origin, note=f"{origin.note}, drift added{note}"
            )
            return name

        return self.cached(("drift", name), make)

    # ------------------------------------------------------------ runs

    def run(self, name: str, method: str) -> Run:
        """The trajectory of log `name` by `method`, computed once and timed."""
        return self.cached(("run", name, method), lambda: self._run(name, method))

    def _run(self, name: str, method: str) -> Run:
        ds = self.dataset(name)
        self.step(f"map {name} ({method})")
        return map_log(self.out, name, ds, method)

    def labels(self, name: str) -> Labelled:
        """Labels of log `name` from its training regions, computed once."""

        def make() -> Labelled:
            ds = self.dataset(name)
            self.step(f"label {name}")
            if name == CORRIDOR:
                sim = self.corridor()
                return label_log(self.out, name, ds, sim.regions, sim.truth())
            source = self.sources[name]
            if source.regions is None:
                raise NotAvailable(f"{name} has no training regions (regions.csv)")
            return label_log(self.out, name, ds, source.regions, source.truth)

        return self.cached(("labels", name), make)

    def logs(self, origin: str | None = None) -> list[str]:
        return [n for n, s in self.sources.items() if origin is None or s.origin == origin]

    def map_logs(self) -> list[str]:
        """The logs mapped by every method: the corridor, the real DP-SLAM loop and the Intel
        lab with drift added (when the real logs are here), then the datasets given.
        `dataset(name)` simulates or imports each on first use (or says not available)."""
        return [CORRIDOR, *self.real_logs(), *self.given()]

    def real_logs(self) -> list[str]:
        return ["dpslam_loop5", INTEL_DRIFT] if self.real_dir is not None else []

    def sectioned_logs(self) -> list[str]:
        """The logs of Table 1 and Fig. 3: the corridor, and the Intel lab with drift when the
        real logs are there."""
        return [CORRIDOR, *([INTEL_DRIFT] if self.real_dir is not None else [])]

    def given(self) -> list[str]:
        """Datasets named on the command line, else the bundled ones."""
        return [n for n, s in self.sources.items() if s.origin in ("command line", "bundled")]

    def labelled_logs(self) -> list[str]:
        """Logs with training regions: the corridor, real logs with regions in
        datasets/real-regions, and the given or bundled logs that come with a regions CSV."""
        real = [
            n for n in REAL_LOGS if self.real_dir and (REAL_REGIONS / f"{n}-regions.csv").is_file()
        ]
        given = [n for n in self.given() if self.sources[n].regions is not None]
        return [CORRIDOR, *real, *given]

    def real_named(self, name: str) -> str:
        fmt, relpath, options = REAL_LOGS[name]
        return self.real_log(name, fmt, relpath, **options)

    @contextmanager
    def part(self, section: Section, what: str) -> Iterator[None]:
        """Run one part of a section; a missing piece marks only that part not available."""
        try:
            yield
        except NotAvailable as e:
            section.unavailable.append(f"{what}: {e}")
