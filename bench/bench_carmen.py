"""CARMEN import and write on real logs: grouped numpy conversion against float() per token.

For each log: the whole import (`Carmen().read`, which converts each message group with one
numpy call), the import to a dataset on disk as `toolkit import` does it (`import_to`:
streamed to Parquet), a baseline that parses the same laser lines with float() per token, and
the writer. Medians over repeats; MB = uncompressed bytes of the log.
"""

from __future__ import annotations

import gzip
import os
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np

from importers.base import open_text
from importers.carmen import Carmen, CarmenOptions

ROOT = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("TOOLKIT_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
LOGS = (
    "carmen_radish_corrected/intel-corrected.log.gz",
    "carmen_radish_corrected/freiburg-campus-corrected.log.gz",
    "csm_laserazos/laserazosSM3.log",
)


def _median(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _per_token(path: Path) -> np.ndarray:
    """The baseline: every laser line split and converted with float() token by token."""
    rows = []
    with open_text(path) as f:
        for line in f:
            tokens = line.split()
            if tokens and tokens[0] == "FLASER":
                n = int(tokens[1])
                rows.append([float(v) for v in tokens[2 : 2 + n]])
    return np.array(rows, dtype=np.float32)


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    repeats = 2 if quick else 5
    logs = LOGS[:1] if quick else LOGS
    rows: list[dict[str, object]] = []
    carmen = Carmen()
    for rel in logs:
        path = REAL / rel
        if not path.exists():
            continue
        opener = gzip.open if path.suffix == ".gz" else open
        with opener(path, "rb") as f:
            size = len(f.read())
        ds = carmen.read([path], CarmenOptions())
        with tempfile.TemporaryDirectory() as tmp:
            sources, target = [path], Path(tmp)
            t_read = _median(partial(carmen.read, sources, CarmenOptions()), repeats)
            stream = partial(carmen.import_to, sources, target / "ds", CarmenOptions(), force=True)
            t_import = _median(stream, repeats)
            t_base = _median(partial(_per_token, path), repeats)
            t_write = _median(partial(carmen.write, ds, target), repeats)
        rows.append(
            {
                "name": Path(rel).name,
                "MB": round(size / 1e6, 2),
                "scans": ds.n_scans,
                "beams": ds.n_beams,
                "import_s": round(t_read, 3),
                "per_token_ranges_only_s": round(t_base, 3),
                "ratio": round(t_base / t_read, 2),
                "write_s": round(t_write, 3),
                "import_MB_per_s": round(size / 1e6 / t_read, 1),
                "import_to_s": round(t_import, 3),
                "import_to_MB_per_s": round(size / 1e6 / t_import, 1),
            }
        )
    return rows
