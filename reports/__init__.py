"""The report: one generator per figure or table of the paper, and the index that shows them.

    from reports import build
    report = build(Path("out/report"), [Path("out/datasets/intel")], quick=True)
    report.sections[0].tables[0].frame      # the data behind every table and figure

A generator is a module with KEY, TITLE, INTRO and `generate(ctx, section)`: it fills the
section with figures and tables (written under the report folder) and the data behind them,
and marks what it cannot show as not available. `GENERATORS` is the order of the report.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from rich.progress import TaskID

from reports import (
    accuracy,
    fig3_pairs,
    fig6_maps,
    fig8_features,
    machine,
    table1_sections,
    table2_clouds,
)
from reports.base import NotAvailable, Section
from reports.context import (
    QUICK_BUNDLED_SCANS,
    RESERVED,
    Context,
    Source,
    catalog_sources,
    default_real,
)
from reports.index import write_index
from toolkit.atomic import atomic_dir, check_output
from toolkit.dataset import check_dataset_dir
from toolkit.errors import ToolkitError
from toolkit.progress import task

GENERATORS: tuple[ModuleType, ...] = (
    table1_sections,
    table2_clouds,
    fig3_pairs,
    fig6_maps,
    fig8_features,
    accuracy,
    machine,
)

__all__ = ["GENERATORS", "Report", "build", "generators", "sources_from_paths"]


def generators(only: Sequence[str] = ()) -> list[ModuleType]:
    """The generator modules, in report order (those whose key is in `only`, if given)."""
    return [m for m in GENERATORS if not only or m.KEY in only]


@dataclass
class Report:
    path: Path
    sections: list[Section]
    seconds: float

    def section(self, key: str) -> Section:
        return next(s for s in self.sections if s.key == key)

    @property
    def failed(self) -> list[Section]:
        return [s for s in self.sections if s.status == "failed"]


def regions_for(path: Path) -> Path | None:
    """A log's training regions: regions.csv inside its folder, or NAME.regions.csv beside it."""
    for candidate in (path / "regions.csv", path.parent / f"{path.name}.regions.csv"):
        if candidate.is_file():
            return candidate
    return None


def sources_from_paths(paths: Sequence[Path], regions: Path | None = None) -> dict[str, Source]:
    """Check the datasets named on the command line (before any work) and name them."""
    if regions is not None and not regions.is_file():
        raise ToolkitError("no such regions file", file=regions)
    sources: dict[str, Source] = {}
    for path in paths:
        check_dataset_dir(path)
        name = path.resolve().name
        k = 2
        while name in sources or name in RESERVED:
            name, k = f"{path.resolve().name}-{k}", k + 1
        sources[name] = Source(name, path, "command line", regions or regions_for(path))
    return sources


def build(
    out: Path,
    datasets: Sequence[Path] = (),
    *,
    regions: Path | None = None,
    quick: bool = False,
    seed: int = 0,
    real: Path | bool | None = True,
    force: bool = False,
    only: Sequence[str] = (),
    command: str | None = None,
    bundled: bool = True,
    on_section: Callable[[Section], None] | None = None,
) -> Report:
    """Run what the report needs and write it to `out` atomically (index.html, figures, tables).

    `real`: True looks for the real logs in the default place, a path names the folder,
    False/None leaves them out. Without `datasets`, the bundled logs of datasets/catalog.json
    are used (unless `bundled` is False). `quick` uses fewer trials and sizes (tests, CI).
    `on_section` is called with each section as soon as it is done (the CLI prints a line).
    """
    out = Path(out)
    check_output(out, force)
    sources = sources_from_paths(list(datasets), regions)
    if not datasets and bundled:
        sources = catalog_sources(max_scans=QUICK_BUNDLED_SCANS if quick else None)
    real_dir = default_real() if real is True else (Path(real) if real else None)
    if real_dir is not None and not real_dir.is_dir():
        raise ToolkitError("no such folder of real logs", file=real_dir)
    mods = generators(only)
    start = time.perf_counter()
    work = Path(tempfile.mkdtemp(prefix="toolkit-report-"))
    try:
        with atomic_dir(out, force=force) as tmp, task("report", len(mods)) as (bar, k):
            ctx = Context(tmp, work, quick=quick, seed=seed, sources=sources, real_dir=real_dir)
            sections = []
            task_id = TaskID(k)
            for mod in mods:

                def step(what: str, title: str = mod.TITLE) -> None:
                    bar.update(task_id, description=f"{title}: {what}")

                ctx.step = step
                step("start")
                sections.append(_generate(mod, ctx))
                bar.advance(task_id)
                if on_section is not None:
                    on_section(sections[-1])
            seconds = time.perf_counter() - start
            header: dict[str, object] = {
                "title": "Learning probabilistic features with laser sensors: results",
                "generated (UTC)": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
                "command": command,
                "mode": "quick (fewer trials and sizes)" if quick else "full",
                "real logs": str(real_dir) if real_dir else "not used",
                "seconds": f"{seconds:.1f}",
            }
            write_index(tmp, sections, header)
            _write_summary(tmp, sections, header)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return Report(out, sections, seconds)


def _generate(mod: ModuleType, ctx: Context) -> Section:
    section = Section(mod.KEY, mod.TITLE, mod.INTRO)
    t0 = time.perf_counter()
    try:
        mod.generate(ctx, section)
    except NotAvailable as e:
        section.unavailable.append(str(e))
    except Exception as e:
        if os.environ.get("TOOLKIT_DEBUG"):
            raise
        section.error = f"{type(e).__name__}: {e}"
        print(f"warning: report section {mod.KEY} failed: {section.error}", file=sys.stderr)
    section.seconds = time.perf_counter() - t0
    return section


def _write_summary(root: Path, sections: Sequence[Section], header: dict[str, object]) -> None:
    """report.json: per section its status, files and what is not available."""
    summary = {
        "header": header,
        "sections": [
            {
                "key": s.key,
                "title": s.title,
                "status": s.status,
                "error": s.error,
                "unavailable": s.unavailable,
                "seconds": round(s.seconds, 3),
                "files": [f for a in s.figures for f in a.files]
                + [f for a in s.tables for f in a.files],
            }
            for s in sections
        ],
    }
    (root / "report.json").write_text(json.dumps(summary, indent=2) + "\n")
