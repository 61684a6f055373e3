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

- floor: `python -c pass` and `python -c "import numpy, pyarrow.parquet"`, the least any
  command that reads a dataset can take on this machine at this load.

Before and after in one run: with BENCH_BASELINE=DIR (another checkout of the toolkit, e.g.
`git archive main | tar -x -C DIR`) every command and the end-to-end map also run from DIR
(`code` = baseline), interleaved with this tree's runs (`code` = this tree), so both see the
same load.

The end-to-end ratios: `wall_over_work` is the wall time over the run's own work as
metrics.json times it (match + local_map + loops + optimisation: the matching, the local-map
matching, loop closure and the pose graph; without loops, match alone); `wall_over_match`
over the scan matching alone (`seconds.match`); `wall_over_kiss_icp` over KISS-ICP's
registration of the same scans, measured in the same run. `outside_run_s`: the wall time
outside the run's stages (the wall less read, compile, matching, loops, optimisation and
outputs): the start (interpreter, imports, typer's parse) and the end (teardown).

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
HEAVY = (
    *("pandas", "numba", "scipy", "scipy.ndimage", "gtsam", "matplotlib", "open3d", "distributed"),
    *("sklearn", "rich"),
)
# where import time goes: libraries and the toolkit's own modules, by cumulative time
SHOWN = (
    *HEAVY,
    *("numpy", "pyarrow", "typer", "pydantic", "rich", "importers", "reports"),
    *("toolkit.dataset", "toolkit.align", "toolkit.mapping", "toolkit.sim", "toolkit.features"),
)
E2E_SCANS, E2E_BEAMS = 5000, 361
_CPU: list[float] = []  # CPU seconds of each child, in order


#: the trees whose `toolkit` is measured: this one, and BENCH_BASELINE's when set
THIS = "this tree"
BASELINE = os.environ.get("BENCH_BASELINE")
CODES = {THIS: ROOT, **({"baseline": Path(BASELINE).resolve()} if BASELINE else {})}
#: metrics.json's stages that are the run's own work (the matching, loops, the pose graph)
WORK = ("local_map", "loops", "optimisation")  # the work besides the sequential matching


#: metrics.json's stages that together make `map_run`'s span (each writer's time and the
#: metrics are inside `outputs`; `total` is the sum of the loop closer's stages)
IN_RUN = (
    *("read", "compile", "prepare", "match", "matching", "compose", "local_map", "loops"),
    *("optimisation", "outputs"),
)


def _outside_run(wall: float, stages: dict[str, float]) -> float:
    """The wall time of a map run outside its stages: the interpreter's start, the imports,
    typer's parse, numba's first-call registries when not in `compile`, the teardown."""
    return wall - sum(stages.get(k, 0.0) for k in IN_RUN)


def _match(stages: dict[str, float]) -> float:
    """The sequential matching's time: `match` (scan-to-keyframe: the pairs alone) or else
    `matching` (scan-to-map, compilation kept out)."""
    return stages.get("match", stages.get("matching", 0.0))


def _env(code: str = THIS, **extra: str) -> dict[str, str]:
    root = str(CODES[code])
    pythonpath = [root, *[p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]]
    if code != THIS:  # the baseline's toolkit, not this tree's
        pythonpath = [root]
    # bytecode written and reused, as in a user's install (this machine's shells set
    # PYTHONDONTWRITEBYTECODE, which made every run compile the toolkit's modules anew)
    environ = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    return {
        **environ,
        "PYTHONPATH": os.pathsep.join(pythonpath),
        "OMP_NUM_THREADS": "1",
        "TOOLKIT_NO_PROGRESS": "1",
        **extra,
    }


def _toolkit(
    *args: object, env: dict[str, str] | None = None, code: str = THIS
) -> tuple[float, str]:
    """Wall time of `python ARGS` in a new process (run in tree `code`), and its stderr; its
    CPU time (user + system, which a loaded machine inflates less than the wall time) is
    appended to `_CPU`."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    result = subprocess.run(
        [sys.executable, *map(str, args)],
        capture_output=True,
        text=True,
        env=env or _env(code),
        cwd=CODES[code],
        timeout=1800,
    )
    seconds = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    _CPU.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    if result.returncode != 0:
        raise RuntimeError(f"{args} failed: {result.stderr.strip()[-1500:]}")
    return seconds, result.stderr


def _imports(args: list[object], code: str = THIS) -> tuple[float, list[str], str]:
    """Seconds of the top-level imports (`-X importtime`), which heavy libraries load, and
    the largest of `SHOWN` with their cumulative seconds."""
    _, log = _toolkit("-X", "importtime", "-m", "toolkit", *args, code=code)
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


def floor_rows(repeats: int) -> list[dict[str, Any]]:
    """The interpreter alone, and with numpy and pyarrow: the floor under every command."""
    rows = []
    for name, code in (
        ("python -c pass", "pass"),
        ("python + numpy + pyarrow.parquet", "import numpy, pyarrow.parquet"),
    ):
        times, cpu = [], []
        for _ in range(repeats + 1):
            seconds, _ = _toolkit("-c", code)
            times.append(seconds)
            cpu.append(_CPU[-1])
        rows.append(
            {
                "table": "floor",
                "name": name,
                "wall_s": round(statistics.median(times[1:]), 3),
                "cpu_s": round(statistics.median(cpu[1:]), 3),
                "load": round(_load(), 2),
            }
        )
    return rows


def startup_rows(work: Path, repeats: int) -> list[dict[str, Any]]:
    data = _small_log(work)
    run = work / "run"
    commands: dict[str, list[object]] = {
        "toolkit --help": ["--help"],
        "toolkit info": ["info", data],
        "toolkit map --method odometry": ["map", data, "--out", run, "--method", "odometry", "-q"],
        "toolkit map (gaussian)": ["map", data, "--out", run, "-q"],
        "toolkit simulate corridor --scans 300": [
            "simulate", "corridor", "--scans", "300", "-f", "dataset", "--out", work / "sim",
        ],
    }  # fmt: skip
    rows = []
    for name, args in commands.items():
        times: dict[str, list[float]] = {code: [] for code in CODES}
        cpu: dict[str, list[float]] = {code: [] for code in CODES}
        stages: dict[str, dict[str, float]] = {code: {} for code in CODES}
        for _ in range(repeats + 1):  # the first run warms the OS and numba's caches
            for code in CODES:  # interleaved: every tree sees the same load
                for leftover in (run, work / "sim"):
                    shutil.rmtree(leftover, ignore_errors=True)
                seconds, _ = _toolkit("-m", "toolkit", *args, code=code)
                times[code].append(seconds)
                cpu[code].append(_CPU[-1])
                if (run / "metrics.json").exists():
                    stages[code] = json.loads((run / "metrics.json").read_text())["seconds"]
        for code in CODES:
            for leftover in (run, work / "sim"):
                shutil.rmtree(leftover, ignore_errors=True)
            imports, heavy, where = _imports(args, code)
            timed = stages[code]
            writing = timed.get("outputs", sum(v for k, v in timed.items() if "." in k))
            rows.append(
                {
                    "table": "startup",
                    "name": name,
                    "code": code,
                    "wall_s": round(statistics.median(times[code][1:]), 3),
                    "cpu_s": round(statistics.median(cpu[code][1:]), 3),
                    "imports_s": round(imports, 3),
                    "read_s": round(timed.get("read", 0.0), 3),
                    "match_s": round(timed.get("match", 0.0), 3),
                    "compile_s": round(timed.get("compile", 0.0), 3),
                    "write_s": round(writing, 3),
                    "heavy_imports": " ".join(heavy) or "-",
                    "largest_imports_s": where,
                    "load": round(_load(), 2),
                }
            )
        for leftover in (run, work / "sim"):
            shutil.rmtree(leftover, ignore_errors=True)
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

    def map_once(env: dict[str, str], code: str) -> tuple[float, float, dict[str, Any]]:
        shutil.rmtree(run, ignore_errors=True)
        seconds, _ = _toolkit("-m", "toolkit", "map", data, "--out", run, "-q", env=env, code=code)
        return seconds, _CPU[-1], json.loads((run / "metrics.json").read_text())

    # the first run of a session without numba's cache (as after a fresh install), then warm
    caches = {code: str(work / f"numba-cache-{i}") for i, code in enumerate(CODES)}
    first_wall, _, first = map_once(_env(NUMBA_CACHE_DIR=caches[THIS]), THIS)
    for code in CODES:
        if code != THIS:  # the baseline's cache warmed too, not timed
            map_once(_env(code, NUMBA_CACHE_DIR=caches[code]), code)
    runs: dict[str, list[tuple[float, float, dict[str, Any]]]] = {code: [] for code in CODES}
    kiss: list[float] = []
    for i in range(repeats):  # interleaved: the trees and KISS-ICP see the same load
        for code in CODES:
            runs[code].append(map_once(_env(code, NUMBA_CACHE_DIR=caches[code]), code))
        if i < max(1, repeats // 2):
            kiss.append(kiss_icp_seconds(ds))
    kiss_s = min(kiss)
    for code in CODES:
        walls = [w for w, _, _ in runs[code]]
        cpus = [c for _, c, _ in runs[code]]
        stages = [m["seconds"] for _, _, m in runs[code]]
        wall = statistics.median(walls)
        match = statistics.median(_match(st) for st in stages)
        work_s = statistics.median(_match(st) + sum(st.get(k, 0.0) for k in WORK) for st in stages)
        middle = sorted(runs[code], key=lambda r: r[0])[len(walls) // 2][2]["seconds"]
        outside = statistics.median(_outside_run(w, m["seconds"]) for w, _, m in runs[code])
        rows.append(
            {
                "table": "end-to-end",
                "name": f"toolkit map, {ds.n_scans} x {ds.n_beams} (simulated building)",
                "code": code,
                "wall_s": round(wall, 3),
                "cpu_s": round(statistics.median(cpus), 3),
                "work_s": round(work_s, 3),
                "wall_over_work": round(wall / work_s, 2),
                "match_s": round(match, 3),
                "wall_over_match": round(wall / match, 2),
                "outside_run_s": round(outside, 3),
                "read_s": round(statistics.median(st.get("read", 0.0) for st in stages), 3),
                "outputs_s": round(statistics.median(st.get("outputs", 0.0) for st in stages), 3),
                "kiss_icp_s": round(kiss_s, 3),
                "wall_over_kiss_icp": round(wall / kiss_s, 3),
                "stages": json.dumps(middle),
                "load": round(_load(), 2),
            }
        )
    second_wall, _, second = runs[THIS][0]
    for label, wall_s, metrics in (
        ("first run, empty numba cache", first_wall, first),
        ("second run", second_wall, second),
    ):
        rows.append(
            {
                "table": "compile",
                "name": f"toolkit map: {label}",
                "code": THIS,
                "wall_s": round(wall_s, 3),
                "match_s": round(_match(metrics["seconds"]), 3),
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
        rows = floor_rows(repeats)
        rows += startup_rows(work, repeats)
        rows += end_to_end_rows(work, repeats, 1000 if quick else E2E_SCANS)
    return rows


if __name__ == "__main__":
    for row in run(Path("out/bench"), "--quick" in sys.argv):
        print(row)
