"""Peak memory of an import against the Parquet it writes (the issue-19 target: at most 3x).

Each import runs in a fresh child process (`python -m toolkit import ...`, as a user runs
it) whose peak RSS (VmHWM) is read from /proc while it runs; `base_mb` is the RSS of a child
that only imports the same modules (interpreter, numpy, pandas, pyarrow, the importer), so
`peak - base` is what the data costs (with Arrow's Parquet writer: its code, paged in on first
use, and its row-group buffers, ~20 MB whatever the log's length). Inputs, generated in a temporary directory and deleted:
  - a CARMEN log of ~85 MB: the real intel-corrected log tiled with shifted times and noise
    on the ranges (5 mm) and the odometry (0.1 mm), so that Parquet cannot deduplicate the
    copies, written by the CARMEN writer (quick: ~20 MB);
  - a Rawseeds SICK_FRONT session of ~1 GB (`bench_import_rawseeds.generate`; quick: 100 MB).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("TOOLKIT_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
INTEL = REAL / "carmen_radish_corrected" / "intel-corrected.log.gz"

BASE = {
    "carmen": "import numpy, pandas, pyarrow.parquet, importers.carmen, toolkit.app.cli",
    "rawseeds": "import numpy, pandas, pyarrow.parquet, importers.rawseeds, toolkit.app.cli",
}


def carmen_log(path: Path, megabytes: float) -> int:
    """The intel log tiled (times shifted by its duration + 1 s each copy) to ~megabytes."""
    from importers.carmen import Carmen, CarmenOptions, write_log
    from toolkit.dataset import Dataset

    ds = Carmen().read([INTEL], CarmenOptions())
    write_log(ds, path)
    copies = max(1, round(megabytes * 1e6 / path.stat().st_size))
    span = float(ds.t[-1] - ds.t[0]) + 1.0
    shift = np.repeat(np.arange(copies) * span, len(ds.t))
    odo = ds.odometry
    assert odo is not None
    tiled_odo = odo.loc[np.tile(np.arange(len(odo)), copies)].reset_index(drop=True)
    tiled_odo["t"] = tiled_odo["t"].to_numpy() + np.repeat(np.arange(copies) * span, len(odo))
    rng = np.random.default_rng(0)  # mm noise per copy, so that Parquet cannot dedupe copies
    for col in ("x", "y", "theta"):  # (odometry too: 0.1 mm, printed with 6 decimals)
        tiled_odo[col] += rng.normal(0, 1e-4, len(tiled_odo))
    ranges = np.tile(ds.ranges, (copies, 1))
    ranges += rng.normal(0, 0.005, ranges.shape).astype(np.float32)
    big = Dataset(
        t=np.tile(ds.t, copies) + shift,
        ranges=ranges,
        laser=ds.laser,
        odometry=tiled_odo,
    )
    write_log(big, path)
    return big.n_scans


def peak_of(cmd: list[str]) -> tuple[float, float, int]:
    """(peak RSS MB, seconds, exit status) of a child, VmHWM polled from /proc until it ends."""
    env = {**os.environ, "TOOLKIT_NO_PROGRESS": "1", "PYTHONPATH": str(ROOT)}
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    peak = 0.0
    while proc.poll() is None:
        try:
            with open(f"/proc/{proc.pid}/status") as status:
                for line in status:
                    if line.startswith("VmHWM:"):
                        peak = max(peak, int(line.split()[1]) / 1024)
        except (FileNotFoundError, ProcessLookupError):
            pass
        time.sleep(0.02)
    _, err = proc.communicate()
    if proc.returncode:
        print(err.strip()[-400:], file=sys.stderr)
    return peak, time.perf_counter() - start, proc.returncode


def measure(fmt: str, src: Path, out: Path, name: str) -> dict[str, object]:
    base, _, _ = peak_of([sys.executable, "-c", BASE[fmt]])
    peak, seconds, code = peak_of(
        [sys.executable, "-m", "toolkit", "import", fmt, str(src), "--out", str(out), "-q"]
    )
    parquet = sum(p.stat().st_size for p in out.glob("*.parquet")) / 1e6 if out.exists() else 0
    files = [src] if src.is_file() else [p for p in src.rglob("*") if p.is_file()]
    size = sum(p.stat().st_size for p in files) / 1e6
    return {
        "name": name,
        "input_mb": round(size, 1),
        "exit": code,
        "seconds": round(seconds, 1),
        "parquet_mb": round(parquet, 1),
        "peak_mb": round(peak, 1),
        "base_mb": round(base, 1),
        "data_mb": round(peak - base, 1),
        "peak_over_parquet": round(peak / parquet, 2) if parquet else None,
        "data_over_parquet": round((peak - base) / parquet, 2) if parquet else None,
    }


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    from bench import bench_import_rawseeds as rs

    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-memory-") as tmp:
        d = Path(tmp)
        log = d / "big.log"
        carmen_log(log, 20 if quick else 85)
        rows.append(measure("carmen", log, d / "carmen-ds", "carmen (intel tiled)"))
        log.unlink()
        session = d / "session"
        session.mkdir()
        mb = 100 if quick else float(os.environ.get("BENCH_RAWSEEDS_MB", 1000))
        rs.generate(session / f"{rs.SESSION}-SICK_FRONT.csv", mb)
        rows.append(measure("rawseeds", session, d / "rawseeds-ds", "rawseeds SICK_FRONT"))
    return rows


if __name__ == "__main__":
    for row in run(Path("out/bench"), "--quick" in sys.argv):
        print(row)
