"""Loop closure and the pose graph on a long log: peak memory and time of `close_loops`, and
of the whole mapper.

Laps of the simulator's building (a closed lap of 128 m, 3,556 scans: the building's own
path closed at its start) driven again and again up to the size, every lap revisiting the
last: the candidates, verifications and the graph grow with the log. The truth is
continuous. Row `close_loops`: loops and graph alone, the sequential estimate the lap's
drifted odometry restarted at the truth every lap (bounded drift, so candidates stay in the
search window; every lap drifts alike, so the loops agree with it and its ATE is not an
accuracy figure). Row `mapper`: `toolkit map`'s work (front end, loops, graph) on the log with
the lap's odometry steps composed along the whole log, so that its drift grows as a real
robot's does (11.6 m ATE at 20,000 scans); its ATE is the mapper's accuracy over the laps.
Each row runs in a child process, so its peak resident memory is its own. 200,000 scans
by default (about three minutes); `BENCH_LOOPS_SCANS=1000000` for a million (about 16
minutes).

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
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from bench import peak_rss_mb

if TYPE_CHECKING:
    from toolkit.dataset import Dataset

LAP_SCANS = 3556  # one lap of the building (128 m), scans as far apart as its own log's


def _tiled(scans: int) -> tuple[Dataset, np.ndarray, np.ndarray, np.ndarray]:
    """The building's lap tiled to `scans`: the dataset (its drifted odometry composed along
    the whole log), that odometry's poses, the lap's odometry restarted from the truth every
    lap (bounded drift), and the truth's poses."""
    from toolkit import se2
    from toolkit.poses import compose_steps
    from toolkit.sim import parameters, simulate
    from toolkit.sim.scenarios import sample_path

    scn, laser, odometry = parameters("building", seed=0)
    lap = np.array([(4.0, 0.0), (40.0, 0.0), (40.0, 24.0), (0.0, 24.0), (0.0, 0.0), (4.0, 0.0)])
    one, times = sample_path(lap, LAP_SCANS, scn.speed, scn.turn_rate)
    one[:, 2] = se2.wrap(one[:, 2])  # the lap ends where and as it starts
    rng = np.random.default_rng(0)
    lap_ranges = laser.measure(scn.world, one, rng)
    lap_odo = odometry.integrate(one, rng)
    order = np.tile(np.arange(LAP_SCANS - 1), -(-scans // (LAP_SCANS - 1)))[:scans]
    gt = one[order]
    # each step as the lap's odometry measured it (its last step ends where the lap starts)
    before = compose_steps(lap_odo[0], se2.between(lap_odo[order[:-1]], lap_odo[order[:-1] + 1]))
    t = scn.t0 + np.arange(scans) * (times[1] - times[0])

    def frame(p: np.ndarray) -> pd.DataFrame:
        return pd.DataFrame({"t": t, "x": p[:, 0], "y": p[:, 1], "theta": p[:, 2]})

    ds = simulate("building", seed=0, scans=2).dataset  # the laser's geometry and metadata
    big = replace(ds, ranges=lap_ranges[order], t=t, odometry=frame(before), groundtruth=frame(gt))
    return big, before, lap_odo[order], gt


def child(scans: int, whole: bool = False) -> dict[str, Any]:
    """Build the tiled log, run `close_loops` on its odometry (or, `whole`, the mapper:
    front end, loops and graph, as `toolkit map` runs them); the figures as one row."""
    from toolkit.metrics import evaluate
    from toolkit.slam.loops import loop_truth_error
    from toolkit.slam.pipeline import SlamConfig, close_loops
    from toolkit.slam.run import slam_trajectory

    big, odometry, per_lap, gt = _tiled(scans)
    before = odometry if whole else per_lap
    built = peak_rss_mb()
    t0, c0 = time.perf_counter(), time.process_time()
    if whole:
        result, run = slam_trajectory(big)
        poses = result.poses
        keys, edges, loops, timings = run.keys, run.edges, run.loops, run.timings
    else:
        poses, keys, edges, loops, timings, _ = close_loops(
            replace(big, odometry=None), before, SlamConfig()
        )
    accepted = [lp for lp in loops if lp.accepted]
    errors = [loop_truth_error(lp, gt) for lp in accepted]
    return {
        "name": "mapper (front end, loops, graph)" if whole else "close_loops",
        "scans": scans,
        "keyframes": len(keys),
        "edges": len(edges),
        "candidates_verified": len(loops),
        "loops": len(accepted),
        "false_loops": sum(1 for e in errors if e[0] > 0.5 or e[1] > 5.0),
        "ate_odometry_m": round(evaluate(before, gt)["ate"]["rmse"], 3),
        "ate_m": round(evaluate(poses, gt)["ate"]["rmse"], 3),
        "seconds": round(time.perf_counter() - t0, 1),
        "cpu_seconds": round(time.process_time() - c0, 1),
        "seconds_matching": round(timings.get("matching", 0.0), 1),
        "seconds_loops": round(timings["loops"], 1),
        "seconds_optimisation": round(timings["optimisation"], 1),
        "rss_log_mb": round(built),
        "peak_rss_mb": round(peak_rss_mb()),
    }


def run(out: Path, quick: bool) -> list[dict[str, Any]]:
    scans = int(os.environ.get("BENCH_LOOPS_SCANS", "20000" if quick else "200000"))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "TOOLKIT_NO_PROGRESS": "1"}
    rows = []
    for whole in ("", "whole"):  # each in a child of its own: its peak RSS is its own
        result = subprocess.run(
            [sys.executable, "-m", "bench.bench_loops_scale", str(scans), whole],
            capture_output=True,
            text=True,
            env=env,
            timeout=3600,
            cwd=Path(__file__).resolve().parents[1],
        )
        if result.returncode != 0:
            raise RuntimeError(f"bench child failed: {result.stderr.strip()[-2000:]}")
        rows.append(json.loads(result.stdout.strip().splitlines()[-1]))
    return rows


if __name__ == "__main__":
    print(json.dumps(child(int(sys.argv[1]), whole=sys.argv[2:] == ["whole"]), default=float))
