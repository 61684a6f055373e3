"""LMS-200 raw captures: telegram search + CRC + decode throughput in MB/s (target: 50 MB/s).

A capture of ~80 MB (quick: ~10 MB) written by the lms200 writer: 361 values in mm per scan,
random ranges, 4 noise bytes between telegrams on average, a bit error rate of 1e-7 (a few
damaged frames) and a cut-off last telegram. Figures, medians of 3 runs on the same file:

- `crc numpy` / `crc numba`: the CRC of every candidate telegram alone, the two
  implementations side by side (numba after a warm-up call: its compile time, about 2 s
  once, then loaded from numba's cache, is not counted);
- `read numpy` / `read numba`: the whole reader (file read, search, CRC, decode, times) to a
  Dataset in memory;
- `numba import + cached kernel`: what the numba path costs a new process before its first
  byte (why numba is the default only for captures of 1 GB or more);
- `toolkit import`: the command in a new process, end to end (start-up, reader with the
  default CRC, Parquet (zstd), sha256 of the sources, meta.json).

Every row checks that the scans found are exactly the writer's intact frames. Besides wall
time, each row gives this process's CPU time: on a machine shared with other work the wall
figure measures the load as much as the code.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from importers.lms200 import (
    LMS200,
    LMS200Options,
    _candidates,
    crc_frames_numba,
    crc_frames_numpy,
    write,
)
from toolkit.dataset import Dataset, LaserGeometry

REPEATS = 3
BEAMS = 361


def _capture(directory: Path, megabytes: float) -> tuple[Path, list[int]]:
    frame = 7 + 2 * BEAMS + 3
    scans = int(megabytes * 1e6 / (frame + 4))
    rng = np.random.default_rng(200)
    ranges = rng.uniform(0.05, 8.5, (scans, BEAMS)).astype(np.float32)
    laser = LaserGeometry.sick_180(BEAMS, range_max=8.191)
    ds = Dataset(t=np.arange(scans) / 75.0, ranges=ranges, laser=laser)
    capture, _, truth = write(
        ds, directory, noise_bytes=4.0, bit_error_rate=1e-7, truncate_last=True, seed=1
    )
    return capture, json.loads(truth.read_text())["intact"]


def _median(fn: Callable[[], Any]) -> tuple[tuple[float, float], Any]:
    """Median wall and CPU (this process) seconds over REPEATS runs, and the last result."""
    wall, cpu, result = [], [], None
    for _ in range(REPEATS):
        t0, c0 = time.perf_counter(), time.process_time()
        result = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return (statistics.median(wall), statistics.median(cpu)), result


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    rows: list[dict[str, object]] = []
    with tempfile.TemporaryDirectory(dir=out) as tmp_name:
        tmp = Path(tmp_name)
        capture, intact = _capture(tmp / "capture", 10.0 if quick else 80.0)
        megabytes = capture.stat().st_size / 1e6
        buf = np.fromfile(capture, np.uint8)
        starts, lengths, _ = _candidates(buf)

        def row(name: str, seconds: tuple[float, float], scans: int | None = None) -> None:
            wall, cpu = seconds
            rows.append(
                {
                    "name": name,
                    "MB": round(megabytes, 1),
                    "seconds": round(wall, 4),
                    "MB_per_s": round(megabytes / wall, 1),
                    "cpu_seconds": round(cpu, 4),
                    "MB_per_cpu_s": round(megabytes / max(cpu, 1e-9), 1),
                    "scans": scans,
                    "intact_frames": len(intact),
                    "candidates": int(starts.size),
                }
            )

        crc_frames_numba(buf[:64], np.array([0]), np.array([8]))  # compiled (or cached) before
        crcs: dict[str, np.ndarray] = {}
        crc_methods: dict[str, Callable[..., np.ndarray]] = {
            "numpy": crc_frames_numpy,
            "numba": crc_frames_numba,
        }
        for method, fn in crc_methods.items():

            def crc_all(fn: Callable[..., np.ndarray] = fn) -> np.ndarray:
                return fn(buf, starts, lengths - 2)

            seconds, crcs[method] = _median(crc_all)
            row(f"crc {method}", seconds)
        assert np.array_equal(crcs["numpy"], crcs["numba"])
        for method in ("numpy", "numba"):

            def read(method: str = method) -> Dataset:
                return LMS200().read([capture], LMS200Options.parse({"crc": method}))

            seconds, ds = _median(read)
            assert ds.n_scans == len(intact), (ds.n_scans, len(intact))
            row(f"read {method}", seconds, ds.n_scans)
        target = tmp / "dataset"

        def fresh(*code: str) -> tuple[float, float]:
            """Wall and CPU seconds of a new Python process (children's CPU time)."""
            before = os.times()
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-c", "\n".join(code)], check=True)
            after = os.times()
            cpu = after.children_user + after.children_system
            return time.perf_counter() - t0, cpu - before.children_user - before.children_system

        def median_of(runs: list[tuple[float, float]]) -> tuple[float, float]:
            return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)

        numba_load = [
            fresh(
                "import numpy as np",
                "from importers._lms200_crc import crc_kernel",
                "crc_kernel(np.zeros(8, np.uint8), np.zeros(1, np.int64), np.ones(1, np.int64))",
            )
            for _ in range(REPEATS)
        ]
        wall, cpu = median_of(numba_load)
        rows.append({"name": "numba import + cached kernel (new process)", "seconds": round(wall, 4), "cpu_seconds": round(cpu, 4)})  # fmt: skip
        cli = [
            fresh(
                "import sys",
                "from toolkit.app.cli import main",
                f"sys.argv = ['toolkit', 'import', 'lms200', {str(capture)!r}, '--out', "
                f"{str(target)!r}, '--force', '--quiet']",
                "main()",
            )
            for _ in range(REPEATS)
        ]
        meta = json.loads((target / "meta.json").read_text())
        assert meta["scans"] == len(intact)
        row(f"toolkit import (new process, crc {meta['capture']['crc_method']}, to Parquet)", median_of(cli), len(intact))  # fmt: skip
        shutil.rmtree(target, ignore_errors=True)
    return rows
