"""Scale-out: scan-pair matching throughput in one process and on Dask LocalClusters of 1, 2, 4.

Rows, all in one run: the single process with one numba thread (the per-core figure) and
with every thread (`none`); then `local:N` (N worker processes, one thread each) in two
modes: `ship` (the client scatters each chunk's scans to the workers, as `toolkit map
--scheduler local:N` does) and `read` (each worker reads its chunk's row group of
scans.parquet itself and the client ships only seeds, indices and the keyframe overlap scan,
as on a scheduler given by address). The log is the simulated building's scans repeated to
50,000 (10,000 with --quick), consecutive pairs seeded by odometry, chunks of one row group
(4,096 scans). Figures, medians of the repeats: pairs/s of the whole call (shipping or
reading included); `in_task_pairs_per_s`, a worker's rate while inside its tasks (reading +
matching), to set beside the one-thread single process: the difference is what a worker
loses to its task; `busy`, the share of the workers' wall time spent inside tasks (the rest
is scheduling, shipping, gathering, and waiting for a core); the cluster's start-up and its
first tiny tasks (each worker loads the numba kernels from the cache, and the Parquet
reader); and whether the poses equal the single-process ones bit for bit. On a shared
machine the figures follow the free cores, not the worker count: quote the load.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from toolkit.dataset import LaserGeometry

CLUSTERS = ("local:1", "local:2", "local:4")


def _log(scans: int) -> tuple[np.ndarray, np.ndarray, Any]:
    from toolkit import se2
    from toolkit.poses import odometry_poses
    from toolkit.sim import simulate

    ds = simulate("building", seed=0).dataset
    odo = odometry_poses(ds)
    assert odo is not None
    steps = se2.laser_motion(se2.between(odo[:-1], odo[1:]), ds.laser)
    copies = -(-scans // ds.n_scans)
    ranges = np.tile(ds.ranges, (copies, 1))[:scans]
    seeds = np.tile(np.vstack([steps, np.zeros((1, 3))]), (copies, 1))[: scans - 1]
    return np.ascontiguousarray(ranges), seeds, ds.laser


def _single(
    ranges: np.ndarray, seeds: np.ndarray, laser: LaserGeometry, repeats: int
) -> list[dict[str, Any]]:
    import numba

    from toolkit.align import scan as sc

    sc.match_pairs(ranges[:50], seeds[:49], laser)  # load the kernels
    rows = []
    every = numba.get_num_threads()
    for threads in (1, every):
        numba.set_num_threads(threads)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            matches = sc.match_pairs(ranges, seeds, laser)
            times.append(time.perf_counter() - t0)
        rate = len(matches) / statistics.median(times)
        rows.append(
            {
                "scheduler": "none",
                "mode": f"{threads} thread{'s' if threads > 1 else ''}",
                "workers": 0,
                "pairs": len(matches),
                "pairs_per_s": round(rate),
                "in_task_pairs_per_s": round(rate / threads),
                "poses": matches.pose,
            }
        )
    numba.set_num_threads(every)
    return rows


def run(out: Path, quick: bool) -> list[dict[str, Any]]:
    from toolkit.app.fleet import client_for
    from toolkit.app.fleet_map import ChunkTimes, match_pairs_on
    from toolkit.dataset import write_scans

    scans = 10_000 if quick else 50_000
    repeats = 2 if quick else 3
    ranges, seeds, laser = _log(scans)
    load = os.getloadavg()[0]
    rows = _single(ranges, seeds, laser, repeats)
    reference = rows[0].pop("poses")
    rows[1]["equal_to_single_process"] = bool(np.array_equal(rows[1].pop("poses"), reference))
    rows[0]["equal_to_single_process"] = True
    with tempfile.TemporaryDirectory() as tmp:
        path, small = Path(tmp) / "scans.parquet", Path(tmp) / "small.parquet"
        write_scans(path, np.arange(scans, dtype=np.float64), ranges)
        write_scans(small, np.arange(50, dtype=np.float64), ranges[:50])
        for scheduler in CLUSTERS:
            workers = int(scheduler.split(":")[1])
            t0 = time.perf_counter()
            with client_for(scheduler) as client:
                started = time.perf_counter() - t0
                t0 = time.perf_counter()
                for warm in (None, small):  # the kernels, and the Parquet reader
                    match_pairs_on(client, ranges[:50], seeds[:49], laser, chunk=10, scans=warm)
                first = time.perf_counter() - t0
                for mode, source in (("ship", None), ("read", path)):
                    walls, inside, busy = [], [], []
                    for _ in range(repeats):
                        times = ChunkTimes()
                        matches = match_pairs_on(
                            client, ranges, seeds, laser, scans=source, times=times
                        )
                        walls.append(times.wall)
                        inside.append(sum(times.pairs) / sum(times.inside))
                        busy.append(sum(times.inside) / (times.wall * workers))
                    rows.append(
                        {
                            "scheduler": scheduler,
                            "mode": mode,
                            "workers": workers,
                            "pairs": len(matches),
                            "pairs_per_s": round(len(matches) / statistics.median(walls)),
                            "in_task_pairs_per_s": round(statistics.median(inside)),
                            "busy": round(statistics.median(busy), 2),
                            "cluster_start_s": round(started, 2),
                            "first_task_s": round(first, 2),
                            "equal_to_single_process": bool(
                                np.array_equal(matches.pose, reference)
                            ),
                        }
                    )
    base = {r["mode"]: r["pairs_per_s"] for r in rows if r["scheduler"] == "local:1"}
    for row in rows:
        row["name"] = f"match {scans} scans"
        row["load_at_start"] = round(load, 2)
        if row["workers"]:
            row["speedup_vs_1_worker"] = round(row["pairs_per_s"] / base[row["mode"]], 2)
    return rows


if __name__ == "__main__":
    import sys

    for row in run(Path("out/bench"), "--quick" in sys.argv):
        print(row)
