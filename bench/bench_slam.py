"""SLAM: odometry, scan-to-keyframe, scan-to-map, the default mapper (scan-to-map, loops), the
previous default (slam-keyframe: scan-to-keyframe, lag edges, loops) and KISS-ICP.

Side by side on the same scans: the real CARMEN logs (Radish "corrected" logs, their corrected
poses as the truth, odometry drifted with `toolkit.poses.with_drift`, seeds 0-2) and the
simulator's corridor and building without odometry (as an LMS-200 capture has none). KISS-ICP
(the bench extra) gets each scan's returns as 3D points at z = 0, deskew off, seeded by the same
odometry (its `last_delta` set to the odometry's motion before each frame; constant velocity
without odometry, its own model); the best of voxel 0.1 / 0.3 m is kept. Per log and method:
ATE (m), RPE (m, deg), relation error (Kümmerle et al., relations derived from the truth),
failures, scans/s, and for the mapper the loops found and the false ones (residual against the
truth above 0.5 m or 5 deg). With two seeds or more, `bench_slam_own.csv`: per real log and
method, the error over 20 m of path split into each seed's own part and the part every seed
shares (`toolkit.metrics.shared_error`): the corrected poses are a SLAM output themselves, and
on infinite-corridor most of the ATE is common to every run (docs/maps.md, session 27), so the
own part is the figure a method's change can move.

A run is chaotic: the odometry moved by 1e-9 m moves edmonton seed 0's ATE over 0.12-0.36 m
(docs/maps.md). `BENCH_SLAM_DRAWS=N` runs every method N times on a log with odometry, draw d > 0
with the odometry's x, y moved by N(0, 1e-9 m) (seeded by d); the row is the median draw's (the
lower middle one for an even N), with the ATE's range over the draws and the false loops of all
of them.

The drift's direction is the same on every seed (REAL_LOG_DRIFT: +2% scale, wheels 0.5% apart,
0.87 deg/m; a seed draws only the wheel noise and the slips), so every default was measured
under it. `BENCH_SLAM_DRIFT` overrides its parameters, a JSON object of `with_drift`'s, e.g.
'{"wheel_diff": -0.005, "scale_error": -0.02}' for the mirror-image drift (docs/maps.md).

    python -m bench --only bench_slam            # every log, seeds 0-2
    BENCH_SLAM_SEEDS=3,4,5 BENCH_SLAM_DRAWS=3 python -m bench --only bench_slam   # held out
    BENCH_SLAM_LOGS=intel,fhw BENCH_SLAM_SEEDS=0 python -m bench --only bench_slam
    BENCH_SLAM_DRAWS=5 BENCH_SLAM_LOGS=edmonton python -m bench --only bench_slam
"""

from __future__ import annotations

import itertools
import json
import os
import tempfile
import time
from collections.abc import Callable, Container, Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from bench import peers
from toolkit import se2
from toolkit.dataset import Dataset
from toolkit.mapping import map_run
from toolkit.metrics import evaluate, relation_error, shared_error, truth_relations
from toolkit.poses import REAL_LOG_DRIFT, build, odometry_poses, truth_poses, with_drift

if TYPE_CHECKING:
    from importers.carmen import CarmenOptions
    from toolkit.slam.pipeline import SlamConfig

ROOT = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("TOOLKIT_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
CARMEN = REAL / "carmen_radish_corrected"
#: drift seeds the mapper was first tuned on (every log's seed 0; some seeds 1-2): the csv's
#: `tuned` column. Since then each session has held out fresh seeds, run them once and spent
#: them for development (docs/maps.md, "Where it stands": 0-50 used, the next set 51 and up)
TUNED_SEEDS = (0, 1, 2)
#: `with_drift`'s parameters for the drift's other direction: REAL_LOG_DRIFT's wheel difference
#: and scale error negated (the defaults were tuned under one; `--mirror`)
MIRRORED_DRIFT = {k: -REAL_LOG_DRIFT[k] for k in ("wheel_diff", "scale_error")}


def drifted_both_ways(
    seeds: tuple[int, ...],
) -> Iterator[tuple[str, int, str, Dataset, np.ndarray]]:
    """Each real log (`real_logs`) drifted by each seed in both directions ("+", "mirrored"):
    its name, the seed, the direction, the drifted log and its odometry at the scan times."""
    for name, ds in real_logs():
        for seed in seeds:
            for direction, drift in (("+", {}), ("mirrored", MIRRORED_DRIFT)):
                log = with_drift(ds, seed, **drift)
                odometry = odometry_poses(log)
                assert odometry is not None
                yield name, seed, direction, log, odometry


def sim_worlds(
    worlds: tuple[int, ...], scans: int | None = None
) -> Iterator[tuple[str, int, Dataset, np.ndarray, np.ndarray]]:
    """The simulator's corridor and building on each world (its seed), of `scans` scans or
    their own count: the scenario, the world, the log, its truth and its odometry."""
    from toolkit.sim import simulate

    for world in ("corridor", "building"):
        for seed in worlds:
            ds = simulate(world, seed=seed, **({"scans": scans} if scans else {})).dataset
            truth, odometry = truth_poses(ds), odometry_poses(ds)
            assert truth is not None and odometry is not None
            yield world, seed, ds, truth, odometry


def ate(poses: np.ndarray, truth: np.ndarray) -> float:
    """The ATE (RMS after SE(2) alignment) of `poses` against `truth`, in m."""
    return float(evaluate(poses, truth)["ate"]["rmse"])


def map_metrics(ds: Dataset) -> dict[str, Any]:
    """`toolkit map`'s metrics.json for `ds` (`toolkit.mapping.map_run`, the run's other
    outputs not written): what the fault benches read its ATE and checks from."""
    with tempfile.TemporaryDirectory() as tmp:
        return map_run(ds, Path(tmp) / "run", outputs=("metrics.json",)).metrics


def map_summary(table: pd.DataFrame, by: list[str], numbers: list[str]) -> pd.DataFrame:
    """Per group of `by`: the medians of `numbers`, the worst `toolkit_map` ATE and how many
    of the group's maps are within 0.5 m (issue #20's target for logs without odometry)."""
    groups = table.groupby(by)
    summary = groups[numbers].median().round(3)
    summary["max"] = groups["toolkit_map"].max().round(3)
    summary["within_0.5"] = groups["toolkit_map"].apply(
        lambda ate: f"{int((ate <= 0.5).sum())}/{len(ate)}"
    )
    return summary


def print_row(row: dict[str, Any]) -> None:
    """One result as `key=value` pairs on a line (floats to 3 decimals), as a bench goes."""
    text = (f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items())
    print(" ".join(text), flush=True)


def real_logs(
    options: CarmenOptions | None = None, names: Container[str] | None = None
) -> Iterator[tuple[str, Dataset]]:
    """The CARMEN corrected logs, their corrected poses as ground truth (`poses=groundtruth`,
    or `options`). Where a log's lines hold one pose for the laser and the robot while the
    laser is mounted off centre (belgioioso, freiburg-101, freiburg-campus: a corrector's scan
    poses) the truth is the robot's behind the laser's poses (`equal_poses=laser`, the
    importer's default since session 34; `equal_poses=robot` the lines' poses as the robot's,
    the reading before it; `laser_x=0` the laser at the robot's centre; docs/journal/maps.md,
    sessions 32 to 34). `names`: only these logs, the rest not read (default: those of
    BENCH_SLAM_LOGS, else all)."""
    from importers.carmen import Carmen, CarmenOptions

    read_as = options or CarmenOptions(poses="groundtruth")
    if names is None:
        names = [w for w in os.environ.get("BENCH_SLAM_LOGS", "").split(",") if w] or None
    for path in sorted(CARMEN.glob("*-corrected.log*")):
        name = path.name.split("-corrected")[0]
        if names is not None and name not in names:
            continue
        yield name, Carmen().read([path], read_as)


def sim_logs(seed: int = 0, names: Container[str] | None = None) -> Iterator[tuple[str, Dataset]]:
    """The simulator's corridor and building: dense logs (4-8 cm between scans, unlike the
    corrected CARMEN logs' ~1 m), with drifted odometry (`-odometry`) and without odometry
    (`-lms200`, an LMS-200 capture's case). `names`: only these, by scenario or log name (e.g.
    corridor, building-lms200), the rest not simulated (default: BENCH_SLAM_LOGS, else all)."""
    from toolkit.sim import simulate

    if names is None:
        names = [w for w in os.environ.get("BENCH_SLAM_LOGS", "").split(",") if w] or None
    for scenario in ("corridor", "building"):
        odometry, lms200 = f"{scenario}-odometry", f"{scenario}-lms200"
        kept = {
            log for log in (odometry, lms200) if names is None or scenario in names or log in names
        }
        if not kept:
            continue
        sim = simulate(scenario, seed=seed)
        if odometry in kept:
            yield odometry, with_drift(sim.dataset, seed)
        if lms200 in kept:
            yield lms200, replace(sim.dataset, odometry=None)


# ---------------------------------------------------------------- methods


def _kiss(ds: Dataset, voxel: float) -> np.ndarray:
    """KISS-ICP's robot poses for `ds` (`bench.peers`), from the odometry's first pose."""
    kiss, frames, seeds = peers.kiss_icp(ds, voxel)
    out = peers.register(kiss, frames, seeds)
    odo = odometry_poses(ds)
    mount = se2.mount_pose(ds.laser)
    start = se2.compose(odo[0], mount) if odo is not None else mount
    laser = se2.compose(np.broadcast_to(start, out.shape), out)
    return se2.compose(laser, np.broadcast_to(se2.inverse(mount), out.shape))


def kiss_best(ds: Dataset) -> tuple[np.ndarray, float, dict[str, Any]]:
    """KISS-ICP at voxel 0.1 and 0.3 m: the run with the better ATE, and its own time."""
    truth = truth_poses(ds)
    best: tuple[float, np.ndarray, float, float] | None = None
    for voxel in (0.1, 0.3):
        t0 = time.perf_counter()
        poses = _kiss(ds, voxel)
        seconds = time.perf_counter() - t0
        ate = evaluate(poses, truth)["ate"]["rmse"] if truth is not None else 0.0
        if not np.isfinite(poses).all():
            ate = np.inf
        if best is None or ate < best[0]:
            best = (ate, poses, seconds, voxel)
    assert best is not None
    return best[1], best[2], {"voxel": best[3]}


def scan_to_keyframe(ds: Dataset) -> tuple[np.ndarray, float, dict[str, Any]]:
    result = build(ds, "gaussian")
    return result.poses, result.seconds, {}


def scan_to_map(ds: Dataset) -> tuple[np.ndarray, float, dict[str, Any]]:
    """The mapper's front end alone: scan-to-map matching, no loops."""
    from toolkit.slam.scanmap import scan_to_map as run_front

    result = run_front(ds)
    return result.poses, result.seconds, {}


def mapper(
    ds: Dataset,
    front_end: str = "map",
    config: SlamConfig | None = None,
) -> tuple[np.ndarray, float, dict[str, Any]]:
    """`toolkit map`'s default: sequential matching (odometry or constant velocity), loops,
    pose graph; timed as metrics.json times it (matching + loops + optimisation).
    `front_end="keyframe"`: the previous default (scan-to-keyframe, lag edges, loops);
    `config`: a whole SlamConfig instead (`bench.paired_maps`' variants)."""
    from toolkit.slam.pipeline import SlamConfig
    from toolkit.slam.run import slam_trajectory

    result, slam = slam_trajectory(ds, slam=config or SlamConfig(front_end=front_end))
    m = slam.metrics(ds)
    extra = {"loops": m["loops"], "false_loops": m.get("false_loops")}
    extra |= {f"s_{k}": round(v, 2) for k, v in m["seconds"].items() if k != "total"}
    return result.poses, m["seconds"]["total"], extra


def methods() -> dict[str, Callable[[Dataset], tuple[np.ndarray, float, dict[str, Any]]]]:
    out: dict[str, Callable[[Dataset], tuple[np.ndarray, float, dict[str, Any]]]] = {
        "scan-to-keyframe": scan_to_keyframe
    }
    out["scan-to-map"] = scan_to_map
    out["slam"] = mapper
    out["slam-keyframe"] = lambda ds: mapper(ds, "keyframe")
    out["kiss-icp"] = kiss_best
    wanted = [w for w in os.environ.get("BENCH_SLAM_METHODS", "").split(",") if w]
    return {k: v for k, v in out.items() if not wanted or k in wanted}


def _row(
    log: str, seed: int, method: str, ds: Dataset, poses: np.ndarray, seconds: float
) -> dict[str, Any]:
    truth = truth_poses(ds)
    assert truth is not None
    m = evaluate(poses, truth)
    rel = relation_error(poses, truth, truth_relations(truth))
    return {
        "log": log,
        "tuned": seed in TUNED_SEEDS,
        "seed": seed,
        "scans": ds.n_scans,
        "method": method,
        "ate_m": round(m["ate"]["rmse"], 3),
        "rpe_m": round(m["rpe"]["translation"], 4),
        "rpe_deg": round(m["rpe"]["rotation_deg"], 3),
        "rel_t_m": round(rel.get("translation_mean", np.nan), 3),
        "rel_r_deg": round(rel.get("rotation_mean_deg", np.nan), 3),
        "failures": m["failures"]["count"],
        "scans_per_s": round(ds.n_scans / seconds, 1) if seconds > 0 else None,
    }


def nudged(ds: Dataset, draw: int) -> Dataset:
    """`ds` itself for draw 0; else its odometry's x, y moved by N(0, 1e-9 m), seeded by `draw`."""
    if draw == 0 or ds.odometry is None:
        return ds
    odometry = ds.odometry.copy()
    rng = np.random.default_rng(draw)
    for axis in ("x", "y"):
        odometry[axis] = odometry[axis] + rng.normal(0.0, 1e-9, len(odometry))
    return replace(ds, odometry=odometry)


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    seeds = [int(s) for s in os.environ.get("BENCH_SLAM_SEEDS", "0,1,2").split(",") if s]
    draws = max(1, int(os.environ.get("BENCH_SLAM_DRAWS", "1")))
    if quick:
        seeds = seeds[:1]
    todo = methods()
    for _name, ds in itertools.islice(sim_logs(0), 2):  # compile before timing anything
        for fn in todo.values():
            if fn is not kiss_best:
                fn(replace(ds, ranges=ds.ranges[:300], t=ds.t[:300], groundtruth=None))
    rows: list[dict[str, object]] = []
    kept: dict[tuple[str, str], list[np.ndarray]] = {}  # real logs: poses per seed
    truths: dict[str, np.ndarray] = {}

    def measure(log: str, seed: int, ds: Dataset, keep: bool = False) -> None:
        truth = truth_poses(ds)
        odo = odometry_poses(ds)
        if odo is not None and truth is not None:
            rows.append({**_row(log, seed, "odometry", ds, odo, 0.0), "scans_per_s": None})
        for name, fn in todo.items():
            runs = []
            for d in range(draws if odo is not None else 1):
                run_ds = nudged(ds, d)
                poses, seconds, extra = fn(run_ds)
                runs.append(
                    {**_row(log, seed, name, run_ds, poses, seconds), **extra, "_poses": poses}
                )
            runs.sort(key=lambda r: float(r["ate_m"]))
            row = runs[(len(runs) - 1) // 2]
            if keep and truth is not None:
                truths[log] = truth
                kept.setdefault((log, name), []).append(row.pop("_poses"))
            row.pop("_poses", None)
            if len(runs) > 1:
                row["draws"] = len(runs)
                row["ate_min"], row["ate_max"] = runs[0]["ate_m"], runs[-1]["ate_m"]
                if "false_loops" in row:
                    row["false_loops"] = sum(int(r["false_loops"] or 0) for r in runs)
            rows.append(row)
            print(
                {k: row[k] for k in ("log", "seed", "method", "ate_m", "scans_per_s")}, flush=True
            )

    drift = {k: float(v) for k, v in json.loads(os.environ.get("BENCH_SLAM_DRIFT", "{}")).items()}
    for name, ds in real_logs():
        for seed in seeds:
            measure(name, seed, with_drift(ds, seed, **drift), keep=True)
    for seed in seeds:
        for name, ds in sim_logs(seed):
            measure(name, seed, ds)
    own = own_parts(kept, truths)
    if own:
        out.mkdir(parents=True, exist_ok=True)
        pd.DataFrame(own).to_csv(out / "bench_slam_own.csv", index=False)
        print(pd.DataFrame(own).to_string(index=False), flush=True)
    return rows


def own_parts(
    kept: dict[tuple[str, str], list[np.ndarray]], truths: dict[str, np.ndarray]
) -> list[dict[str, object]]:
    """Per real log and method run on two seeds or more: the error over 20 m of the truth's
    path, each seed's own part and the part every seed shares (m, deg)."""
    own = []
    for (log, method), poses in kept.items():
        if len(poses) < 2:
            continue
        split = shared_error(poses, truths[log], 20.0)
        own.append(
            {
                "log": log,
                "method": method,
                "seeds": split.runs,
                "own_20m_m": round(split.translation_own, 3),
                "common_20m_m": round(split.translation_common, 3),
                "own_20m_deg": round(float(np.degrees(split.rotation_own)), 3),
                "common_20m_deg": round(float(np.degrees(split.rotation_common)), 3),
            }
        )
    return own
