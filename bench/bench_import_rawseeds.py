"""Rawseeds SICK_FRONT import: MB/s of CSV text and the importer's peak memory (RSS).

Generates a SICK_FRONT CSV like Rawseeds writes it (t with microseconds, 181, 0, 181 ranges
with 3 decimals: a corridor with noise, some no-return 81.910 codes) of ~100 MB and, unless
quick, ~1 GB, in a temporary directory; each import runs in a child process that reports its
own wall and CPU time and peak RSS (`bench.peak_rss_mb`). The 100 MB import is repeated 3 times
(median); the full run adds the 100 MB file bz2-compressed (as Rawseeds ships it) and the
1 GB file, once each. Every file is deleted afterwards.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa

from importers import rawseeds

SESSION = "Bench_2009-02-27a"
T0 = 1235714832.018787  # the start of Bicocca 27a
POOL = 4096  # distinct range lines; timestamps are all distinct

CHILD = """
import json, sys, time
from pathlib import Path
from importers.rawseeds import Rawseeds
from importers.rawseeds import RawseedsOptions
from bench import peak_rss_mb
src, out = Path(sys.argv[1]), Path(sys.argv[2])
start, cpu = time.perf_counter(), time.process_time()
Rawseeds().import_to([src], out, RawseedsOptions())
seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
meta = json.loads((out / "meta.json").read_text())
print(json.dumps({"seconds": seconds, "cpu_seconds": cpu, "scans": meta["scans"],
                  "peak_mb": peak_rss_mb()}))
"""
ROOT = Path(__file__).resolve().parents[1]  # the child imports `bench` from here


def range_pool(seed: int = 0) -> list[str]:
    """POOL scans of a robot in a 3 m corridor, formatted as Rawseeds does ('%.3f')."""
    rng = np.random.default_rng(seed)
    angles = np.deg2rad(np.arange(-90.0, 91.0))
    y = rng.uniform(0.8, 2.2, (POOL, 1))
    s = np.sin(angles)
    with np.errstate(divide="ignore"):
        dist = np.where(s > 1e-9, (3.0 - y) / s, np.where(s < -1e-9, -y / s, np.inf))
    ranges = np.minimum(dist, rng.uniform(8, 40, (POOL, 1))) + rng.normal(0, 0.01, (POOL, 181))
    ranges[rng.random((POOL, 181)) < 0.01] = np.nan  # written as the no-return code
    lines = rawseeds.sick_lines(np.zeros(POOL), ranges.astype(np.float32)).splitlines()
    return [line.split(",", 3)[3] for line in lines]


def generate(path: Path, megabytes: float) -> int:
    """Write a SICK_FRONT CSV of about `megabytes` MB; returns the number of scans."""
    pool = range_pool()
    line_bytes = len(pool[0]) + 25
    scans = int(megabytes * 1e6 / line_bytes)
    rng = np.random.default_rng(1)
    block = 50_000
    with open(path, "w") as f:
        for start in range(0, scans, block):
            k = np.arange(start, min(start + block, scans))
            t = T0 + k / 75.0 + rng.uniform(0, 2e-4, len(k))  # 75 Hz with jitter
            stamps = rawseeds.fixed_text(t, 6).to_pylist()
            picks = rng.integers(0, POOL, len(k))
            f.write("".join(f"{s},181,0,{pool[p]}\n" for s, p in zip(stamps, picks, strict=True)))
    return scans


def import_once(src: Path, out: Path) -> dict[str, float]:
    """Import in a fresh child process: its own wall time and peak RSS."""
    res = subprocess.run(
        [sys.executable, "-c", CHILD, str(src), str(out)],
        capture_output=True,
        text=True,
        check=False,
        env={**os.environ, "TOOLKIT_NO_PROGRESS": "1"},
        cwd=ROOT,
    )
    if res.returncode != 0:
        raise RuntimeError(f"import failed: {res.stderr.strip()[-500:]}")
    result: dict[str, float] = json.loads(res.stdout.strip().splitlines()[-1])
    return result


def measure(
    directory: Path, megabytes: float, repeats: int, bz2: bool = False
) -> dict[str, object]:
    """Generate, import `repeats` times (each in a child), delete; one row of figures.
    With bz2 the file is compressed first (as Rawseeds ships it); MB/s counts the CSV text."""
    src = directory / f"{SESSION}-SICK_FRONT.csv"
    scans = generate(src, megabytes)
    size_mb = src.stat().st_size / 1e6
    if bz2:
        packed = src.with_name(src.name + ".bz2")
        with pa.input_stream(str(src)) as f, pa.output_stream(str(packed), compression="bz2") as g:
            while block := f.read(1 << 22):
                g.write(block)
        src.unlink()
        src = packed
    runs = []
    try:
        for i in range(repeats):
            out = directory / f"ds{i}"
            runs.append(import_once(src, out))
            shutil.rmtree(out, ignore_errors=True)
            if runs[-1]["scans"] != scans:
                raise RuntimeError(f"imported {runs[-1]['scans']} scans of {scans}")
    finally:
        src.unlink()
    seconds = statistics.median(r["seconds"] for r in runs)
    cpu = statistics.median(r["cpu_seconds"] for r in runs)
    return {
        "name": f"rawseeds SICK_FRONT {size_mb:.0f} MB" + (" .bz2" if bz2 else ""),
        "size_mb": round(size_mb, 1),
        "scans": scans,
        "repeats": repeats,
        "seconds": round(seconds, 3),
        "mb_per_s": round(size_mb / seconds, 1),
        "cpu_seconds": round(cpu, 3),  # both cores' time: the cost when the machine is shared
        "mb_per_cpu_s": round(size_mb / cpu, 1),
        "peak_mb": round(max(r["peak_mb"] for r in runs), 1),
    }


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-rawseeds-") as tmp:
        rows.append(measure(Path(tmp), 100, repeats=3))
        if not quick:
            rows.append(measure(Path(tmp), 100, repeats=1, bz2=True))
            rows.append(measure(Path(tmp), 1000, repeats=1))
    return rows


if __name__ == "__main__":
    quick = "--quick" in sys.argv
    for row in run(Path("out/bench"), quick):
        print(row)
