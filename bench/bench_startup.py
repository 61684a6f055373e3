"""Start-up and end to end: each command's wall time in a new process and where it goes; `toolkit map` on a 5,000-scan log against its own matching and KISS-ICP.

Rows (column `table`):
- startup: each command on a small log (the simulated corridor, 300 scans x 181 beams), run
  as a user runs it (`python -m toolkit ...`, a new process): wall time (median of
  `REPEATS`), the time its imports take (`python -X importtime`, the top-level modules'
  cumulative times, one more run), the heavy libraries it loads, and for `map` the stages
  its metrics.json reports (read, match, every output).
- end-to-end: `toolkit map` (a new process, every output written) on a 5,000-scan x
  361-beam simulated building (the paper's 0.5° laser), against its own matching time
  (metrics.json: compilation kept out) and KISS-ICP's registration time on the same scans
  (in this process, one thread, seeded by the same odometry, deskew off, voxel 0.3 m); and
  the first map run of a fresh numba cache (compilation) next to a later one, pairs/s each.

Every child runs with OMP_NUM_THREADS=1 and TOOLKIT_NO_PROGRESS=1; numba's threads as
configured. Wall times on a shared machine vary with its load: the row carries `load`
(the 1-minute load average when the row was measured).
"""

from __future__ import annotations

import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from toolkit.dataset import Dataset

ROOT = Path(__file__).resolve().parents[1]
REPEATS = 3
HEAVY = ("pandas", "numba", "scipy", "matplotlib", "open3d", "distributed", "sklearn")
# where import time goes: libraries and the toolkit's own modules, by cumulative time
SHOWN = (
    *HEAVY,
    *("numpy", "pyarrow", "typer", "pydantic", "rich", "importers", "reports"),
    *("toolkit.dataset", "toolkit.align", "toolkit.mapping", "toolkit.sim", "toolkit.features"),
)
E2E_SCANS, E2E_BEAMS = 5000, 361
_CPU: list[float] = []  # CPU seconds of each child, in order


def _env(**extra: str) -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1", "TOOLKIT_NO_PROGRESS": "1", **extra}


def _toolkit(*args: object, env: dict[str, str] | None = None) -> tuple[float, str]:
    """Wall time of `python ARGS` in a new process, and its stderr; its CPU time (user +
    system, which a loaded machine inflates less than the wall time) in `_toolkit.cpu`."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    result = subprocess.run(
        [sys.executable, *map(str, args)],
        capture_output=True,
        text=True,
        env=env or _env(),
        cwd=ROOT,
        timeout=1800,
    )
    seconds = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    _CPU.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    if result.returncode != 0:
        raise RuntimeError(f"{args} failed: {result.stderr.strip()[-1500:]}")
    return seconds, result.stderr


def _imports(args: list[object]) -> tuple[float, list[str], str]:
    """Seconds of the top-level imports (`-X importtime`), which heavy libraries load, and
    the largest of `SHOWN` with their cumulative seconds."""
    _, log = _toolkit("-X", "importtime", "-m", "toolkit", *args)
    total, heavy = 0.0, set()
    shown: dict[str, float] = {}
    for line in log.splitlines():
        m = re.match(r"import time:\s+\d+ \|\s+(\d+) \|( *)(\S+)", line)
        if not m:
            continue
        cumulative, depth, name = int(m.group(1)), len(m.group(2)), m.group(3)
        if depth <= 1:
            total += cumulative / 1e6
        if name in HEAVY:
            heavy.add(name)
        if name in SHOWN and name not in shown:
            shown[name] = cumulative / 1e6
    top = sorted(shown.items(), key=lambda kv: -kv[1])[:6]
    return total, sorted(heavy), ", ".join(f"{k} {v:.2f}" for k, v in top if v >= 0.01)


def _load() -> float:
    return os.getloadavg()[0]


def _small_log(work: Path) -> Path:
    sys.path.insert(0, str(ROOT))
    import toolkit
    from toolkit.sim import simulate

    out = work / "corridor"
    toolkit.save(simulate("corridor", seed=0, scans=300).dataset, out)
    return out


def startup_rows(work: Path, repeats: int) -> list[dict[str, Any]]:
    data = _small_log(work)
    run = work / "run"
    commands: dict[str, list[object]] = {
        "toolkit --help": ["--help"],
        "toolkit info": ["info", data],
        "toolkit map --method odometry": ["map", data, "-o", run, "--method", "odometry", "-q"],
        "toolkit map (gaussian)": ["map", data, "-o", run, "-q"],
        "toolkit simulate corridor --scans 300": [
            "simulate", "corridor", "--scans", "300", "-f", "dataset", "-o", work / "sim",
        ],
    }  # fmt: skip
    rows = []
    for name, args in commands.items():
        times, cpu = [], []
        stages: dict[str, float] = {}
        for _ in range(repeats + 1):  # the first run warms the OS and numba's caches
            for leftover in (run, work / "sim"):
                shutil.rmtree(leftover, ignore_errors=True)
            seconds, _ = _toolkit("-m", "toolkit", *args)
            times.append(seconds)
            cpu.append(_CPU[-1])
            if (run / "metrics.json").exists():
                stages = json.loads((run / "metrics.json").read_text())["seconds"]
        for leftover in (run, work / "sim"):
            shutil.rmtree(leftover, ignore_errors=True)
        imports, heavy, where = _imports(args)
        writing = sum(v for k, v in stages.items() if "." in k)
        rows.append(
            {
                "table": "startup",
                "name": name,
                "wall_s": round(statistics.median(times[1:]), 3),
                "cpu_s": round(statistics.median(cpu[1:]), 3),
                "imports_s": round(imports, 3),
                "read_s": round(stages.get("read", 0.0), 3),
                "match_s": round(stages.get("match", 0.0), 3),
                "compile_s": round(stages.get("compile", 0.0), 3),
                "write_s": round(writing, 3),
                "heavy_imports": " ".join(heavy) or "-",
                "largest_imports_s": where,
                "load": round(_load(), 2),
            }
        )
    return rows


def kiss_icp_seconds(ds: Dataset, voxel: float = 0.3) -> float:
    """KISS-ICP's registration time on every scan of `ds` (`bench.peers`: points at z = 0,
    seeded with the odometry's laser motion, deskew off, one thread)."""
    from bench import peers

    kiss, frames, seeds = peers.kiss_icp(ds, voxel)
    t0 = time.perf_counter()
    peers.register(kiss, frames, seeds)
    return time.perf_counter() - t0


def end_to_end_rows(work: Path, repeats: int, scans: int) -> list[dict[str, Any]]:
    import toolkit
    from toolkit.sim import simulate

    data = work / "building"
    toolkit.save(simulate("building", seed=0, scans=scans, beams=E2E_BEAMS).dataset, data)
    ds = toolkit.load(data)
    run = work / "e2e"
    rows = []
    cpus: list[float] = []

    def map_once(env: dict[str, str]) -> tuple[float, dict[str, Any]]:
        shutil.rmtree(run, ignore_errors=True)
        seconds, _ = _toolkit("-m", "toolkit", "map", data, "-o", run, "-q", env=env)
        cpus.append(_CPU[-1])
        return seconds, json.loads((run / "metrics.json").read_text())

    # the first run of a session without numba's cache (as after a fresh install), then warm
    cold = _env(NUMBA_CACHE_DIR=str(work / "numba-cache"))
    first_wall, first = map_once(cold)
    second_wall, second = map_once(cold)
    walls, matches = [second_wall], [second["seconds"]["match"]]
    for _ in range(repeats - 1):
        wall, metrics = map_once(cold)
        walls.append(wall)
        matches.append(metrics["seconds"]["match"])
    kiss = [kiss_icp_seconds(ds) for _ in range(max(1, repeats // 2))]
    wall, match, kiss_s = statistics.median(walls), statistics.median(matches), min(kiss)
    rows.append(
        {
            "table": "end-to-end",
            "name": f"toolkit map, {ds.n_scans} x {ds.n_beams} (simulated building)",
            "wall_s": round(wall, 3),
            "cpu_s": round(statistics.median(cpus[1:]), 3),
            "match_s": round(match, 3),
            "wall_over_match": round(wall / match, 2),
            "kiss_icp_s": round(kiss_s, 3),
            "wall_over_kiss_icp": round(wall / kiss_s, 3),
            "stages": json.dumps(second["seconds"]),
            "load": round(_load(), 2),
        }
    )
    for label, wall_s, metrics in (
        ("first run, empty numba cache", first_wall, first),
        ("second run", second_wall, second),
    ):
        rows.append(
            {
                "table": "compile",
                "name": f"toolkit map: {label}",
                "wall_s": round(wall_s, 3),
                "match_s": round(metrics["seconds"]["match"], 3),
                "compile_s": round(metrics["seconds"]["compile"], 3),
                "pairs_per_second": round(metrics["pairs_per_second"]),
                "load": round(_load(), 2),
            }
        )
    return rows


def run(out: Path, quick: bool) -> list[dict[str, Any]]:
    repeats = 2 if quick else REPEATS
    with tempfile.TemporaryDirectory(prefix="bench-startup-") as tmp:
        work = Path(tmp)
        rows = startup_rows(work, repeats)
        rows += end_to_end_rows(work, repeats, 1000 if quick else E2E_SCANS)
    return rows


if __name__ == "__main__":
    for row in run(Path("out/bench"), "--quick" in sys.argv):
        print(row)
