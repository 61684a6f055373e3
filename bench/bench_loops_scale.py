"""Loop closure and the pose graph on a long log: peak memory and time of `close_loops`, and
of the whole mapper.

The simulator's building (4,000 scans, a lap with drifted odometry) tiled to the size, each
lap from the truth's start, so every lap revisits the last: the candidates, verifications
and the graph grow with the log. Row `close_loops`: the sequential estimate is the drifted
odometry (loops and graph alone). Row `mapper`: `toolkit map`'s work, front end included,
on the log with its odometry tiled alongside. The tiles teleport back to the start once per
lap (odometry and truth alike), which the front end composes onto its corrected pose, so the
mapper's laps lie off each other: its ATE is not meaningful and its false loops (places that
only look alike, paired across laps metres apart) are a robustness figure, not an accuracy
one. Each row runs in a child process, so its peak resident memory is its own. 200,000 scans
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


def _tiled(scans: int) -> tuple[Dataset, np.ndarray, np.ndarray]:
    """The building tiled to `scans`: the dataset (its drifted odometry tiled alongside), the
    odometry's poses and the truth's."""
    from toolkit.poses import odometry_poses, truth_poses
    from toolkit.sim import simulate

    ds = simulate("building", seed=0).dataset
    odo, truth = odometry_poses(ds), truth_poses(ds)
    assert odo is not None and truth is not None
    laps = -(-scans // ds.n_scans)
    span = ds.t[-1] - ds.t[0] + 0.1
    t = (np.tile(ds.t, laps) + np.repeat(np.arange(laps) * span, ds.n_scans))[:scans]
    gt = np.tile(truth, (laps, 1))[:scans]
    before = np.tile(odo, (laps, 1))[:scans]

    def frame(p: np.ndarray) -> pd.DataFrame:
        return pd.DataFrame({"t": t, "x": p[:, 0], "y": p[:, 1], "theta": p[:, 2]})

    ranges = np.tile(ds.ranges, (laps, 1))[:scans]
    big = replace(ds, ranges=ranges, t=t, odometry=frame(before), groundtruth=frame(gt))
    return big, before, gt


def child(scans: int, whole: bool = False) -> dict[str, Any]:
    """Build the tiled log, run `close_loops` on its odometry (or, `whole`, the mapper:
    front end, loops and graph, as `toolkit map` runs them); the figures as one row."""
    from toolkit.slam.loops import loop_truth_error
    from toolkit.slam.pipeline import SlamConfig, close_loops
    from toolkit.slam.run import slam_trajectory

    big, before, gt = _tiled(scans)
    built = peak_rss_mb()
    t0, c0 = time.perf_counter(), time.process_time()
    if whole:
        _, run = slam_trajectory(big)
        keys, edges, loops, timings = run.keys, run.edges, run.loops, run.timings
    else:
        _, keys, edges, loops, timings, _ = close_loops(
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
