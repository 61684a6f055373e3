"""Loop closure and the pose graph on a long log: peak memory and time of `close_loops`.

The simulator's building (4,000 scans, a lap with drifted odometry) tiled to the size, each
lap from the truth's start, so every lap revisits the last: the candidates, verifications
and the graph grow with the log. The sequential estimate is the drifted odometry (the front
end's own memory is `bench_scanmatch`'s). Run in a child process, so its peak resident memory
is its own. 200,000 scans by default (about two minutes); `BENCH_LOOPS_SCANS=1000000` for a
million (about 6 minutes of CPU).

    BENCH_LOOPS_SCANS=1000000 python -m bench --only bench_loops_scale
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from bench import peak_rss_mb


def child(scans: int) -> dict[str, Any]:
    """Build the tiled log, run `close_loops` on it; the figures as one row."""
    from toolkit.poses import odometry_poses, truth_poses
    from toolkit.sim import simulate
    from toolkit.slam.loops import loop_truth_error
    from toolkit.slam.pipeline import SlamConfig, close_loops

    ds = simulate("building", seed=0).dataset
    odo, truth = odometry_poses(ds), truth_poses(ds)
    assert odo is not None and truth is not None
    laps = -(-scans // ds.n_scans)
    span = ds.t[-1] - ds.t[0] + 0.1
    t = (np.tile(ds.t, laps) + np.repeat(np.arange(laps) * span, ds.n_scans))[:scans]
    gt = np.tile(truth, (laps, 1))[:scans]
    before = np.tile(odo, (laps, 1))[:scans]
    truth_frame = pd.DataFrame({"t": t, "x": gt[:, 0], "y": gt[:, 1], "theta": gt[:, 2]})
    big = replace(
        ds,
        ranges=np.tile(ds.ranges, (laps, 1))[:scans],
        t=t,
        odometry=None,
        groundtruth=truth_frame,
    )
    del ds
    built = peak_rss_mb()
    t0, c0 = time.perf_counter(), time.process_time()
    _, keys, edges, loops, timings, _ = close_loops(big, before, SlamConfig())
    accepted = [lp for lp in loops if lp.accepted]
    errors = [loop_truth_error(lp, gt) for lp in accepted]
    return {
        "name": "close_loops",
        "scans": scans,
        "keyframes": len(keys),
        "edges": len(edges),
        "candidates_verified": len(loops),
        "loops": len(accepted),
        "false_loops": sum(1 for e in errors if e[0] > 0.5 or e[1] > 5.0),
        "seconds": round(time.perf_counter() - t0, 1),
        "cpu_seconds": round(time.process_time() - c0, 1),
        "seconds_loops": round(timings["loops"], 1),
        "seconds_optimisation": round(timings["optimisation"], 1),
        "rss_log_mb": round(built),
        "peak_rss_mb": round(peak_rss_mb()),
    }


def run(out: Path, quick: bool) -> list[dict[str, Any]]:
    scans = int(os.environ.get("BENCH_LOOPS_SCANS", "20000" if quick else "200000"))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "TOOLKIT_NO_PROGRESS": "1"}
    result = subprocess.run(
        [sys.executable, "-m", "bench.bench_loops_scale", str(scans)],
        capture_output=True,
        text=True,
        env=env,
        timeout=3600,
        cwd=Path(__file__).resolve().parents[1],
    )
    if result.returncode != 0:
        raise RuntimeError(f"bench child failed: {result.stderr.strip()[-2000:]}")
    row: dict[str, Any] = json.loads(result.stdout.strip().splitlines()[-1])
    return [row]


if __name__ == "__main__":
    print(json.dumps(child(int(sys.argv[1])), default=float))
