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
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from importers.base import Importer
from toolkit.atomic import atomic_dir
from toolkit.dataset import write_dataset_files
from toolkit.errors import ToolkitError
from toolkit.sim import Simulation

TRUTH = "truth.parquet"
REGIONS = "regions.csv"
SIMULATION = "simulation.json"
DATASET_FORMAT = "dataset"


def write_truth(sim: Simulation, directory: Path) -> list[Path]:
    """truth.parquet, regions.csv and simulation.json (without the file list) in `directory`."""
    truth = directory / TRUTH
    pq.write_table(
        pa.Table.from_pandas(sim.truth(), preserve_index=False), truth, compression="zstd"
    )
    regions = directory / REGIONS
    sim.regions.to_csv(regions, index=False, float_format="%.6f")
    return [truth, regions]


def write_simulation(
    sim: Simulation, out: str | Path, fmt: str, force: bool = False, **options: object
) -> list[Path]:
    """Write `sim` in format `fmt` under the directory `out`, atomically; the files (in `out`)."""

    out = Path(out)
    if fmt == "lms200":  # the capture's unit mode is the simulated scanner's
        options.setdefault("units", sim.params.get("units", "cm"))
    writer = None if fmt == DATASET_FORMAT else _writer(fmt)  # before any work
    with atomic_dir(out, force=force) as tmp:
        if writer is None:
            write_dataset_files(sim.dataset, tmp)
            native = sorted(tmp.iterdir())
        else:
            try:
                native = [Path(p) for p in writer.write(sim.dataset, tmp, **options)]
            except TypeError as e:
                if "unexpected keyword argument" not in str(e):
                    raise
                raise ToolkitError(f"{fmt} writer: {e}") from None
        truth = write_truth(sim, tmp)
        record = {
            "scenario": sim.scenario,
            "seed": sim.seed,
            "format": fmt,
            "writer_options": {k: _plain(v) for k, v in options.items()},
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
    import importers

    names = importers.names()
    return [n for n in names if type(importers.get(n)).write is not Importer.write] + [
        DATASET_FORMAT
    ]


def _writer(fmt: str) -> Importer:
    import importers

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


def _plain(value: object) -> str | int | float | bool | None:
    return value if isinstance(value, str | int | float | bool) or value is None else str(value)
