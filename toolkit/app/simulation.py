"""A simulation on disk: the native files from a format's writer, plus the truth beside them.

    DIR/<native files>     what importers.get(FORMAT).write produced (or a dataset dir for
                           FORMAT "dataset": scans.parquet, odometry, groundtruth, meta.json)
    DIR/truth.parquet      t, x, y, theta (true robot pose), label, section; one row per scan
    DIR/regions.csv        feature,start,end: 10 consecutive scans per feature (timestamps)
    DIR/simulation.json    scenario, seed, every model parameter, format, files written

DIR is written to a temporary directory and renamed into place (toolkit.atomic.atomic_dir).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

import importers
from importers.base import FormatOptions, Importer
from toolkit.atomic import atomic_dir
from toolkit.dataset import write_dataset_files, write_described
from toolkit.errors import ToolkitError
from toolkit.sim import Simulation

TRUTH = "truth.parquet"
REGIONS = "regions.csv"
SIMULATION = "simulation.json"
DATASET_FORMAT = "dataset"


def write_truth(sim: Simulation, directory: Path) -> list[Path]:
    """truth.parquet, regions.csv and simulation.json (without the file list) in `directory`."""
    truth = directory / TRUTH
    write_described(truth, sim.truth(), "truth")
    regions = directory / REGIONS
    sim.regions.to_csv(regions, index=False, float_format="%.6f")
    return [truth, regions]


def write_simulation(
    sim: Simulation, out: str | Path, fmt: str, force: bool = False, **options: object
) -> list[Path]:
    """Write `sim` in format `fmt` under the directory `out`, atomically; the files (in `out`).

    `options`: the writer's options (`toolkit formats` lists them), as text or plain values;
    parsed into the format's typed write options before any work (unknown ones: an error)."""
    out = Path(out)
    if fmt == "lms200":  # the capture's unit mode is the simulated scanner's
        options.setdefault("units", sim.params.get("units", "cm"))
    writer = None if fmt == DATASET_FORMAT else _writer(fmt)  # before any work
    if writer is None and options:
        raise ToolkitError(f"format {DATASET_FORMAT} has no options; given {', '.join(options)}")
    typed = None if writer is None else importers.write_options(writer, options)
    with atomic_dir(out, force=force) as tmp:
        if writer is None:
            write_dataset_files(sim.dataset, tmp)
            native = sorted(tmp.iterdir())
        else:
            native = [Path(p) for p in writer.write(sim.dataset, tmp, typed)]
        truth = write_truth(sim, tmp)
        record = {
            "scenario": sim.scenario,
            "seed": sim.seed,
            "format": fmt,
            "writer_options": {} if typed is None else _plain_fields(typed, options),
            "scans": sim.dataset.n_scans,
            "beams": sim.dataset.n_beams,
            "params": sim.params,
            "labels": _counts(sim),
            "regions": sim.regions.to_dict(orient="records"),
            "files": [str(p.relative_to(tmp)) for p in native],
            "truth": [str(p.relative_to(tmp)) for p in truth],
        }
        (tmp / SIMULATION).write_text(json.dumps(record, indent=2, allow_nan=False) + "\n")
        files = [p.relative_to(tmp) for p in [*native, *truth, tmp / SIMULATION]]
    return [out / p for p in files]


def writer_formats() -> list[str]:
    """The formats the simulator can write: those whose importer has a writer, and dataset."""
    return [n for n in importers.names() if importers.get(n).writes] + [DATASET_FORMAT]


def _writer(fmt: str) -> Importer[Any, Any]:
    known = writer_formats()
    if fmt not in known:
        if fmt in importers.names():
            raise ToolkitError(
                f"format {fmt!r} has no writer; formats with one: {', '.join(known)}"
            )
        raise ToolkitError(
            f"cannot write format {fmt!r}; formats with a writer: {', '.join(known)}"
        )
    return importers.get(fmt)


def _counts(sim: Simulation) -> dict[str, int]:
    labels, counts = np.unique(sim.labels, return_counts=True)
    return {str(k): int(v) for k, v in zip(labels, counts, strict=True)}


def _plain_fields(options: FormatOptions, given: Iterable[str]) -> dict[str, Any]:
    """The options given, as parsed (typed), in JSON values."""
    plain = (str, int, float, bool, type(None))
    values = {k: getattr(options, k) for k in given}
    return {k: v if isinstance(v, plain) else str(v) for k, v in values.items()}
