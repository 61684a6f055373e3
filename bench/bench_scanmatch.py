"""Whole-log scan matching: Gaussian matcher against ICP (speed, accuracy per log), 1M-scan memory.

Rows (column `table`):
- speed: pairs per second on 181-beam scans (the simulated building), the Gaussian matcher
  over the whole log at once (numba's threads; and on one thread, per core as ICP runs)
  against 2D point-to-line ICP and Open3D point-to-point ICP on the same pairs, with the
  same seeds, correspondence distance and cap on rounds (ICP on a sample of pairs: it runs
  one pair at a time); medians of repeats.
- accuracy: per log (simulated corridor and building; real CARMEN logs with the corrected
  poses as truth and seeded odometry drift, `toolkit.poses.REAL_LOG_DRIFT`) and method:
  ATE after SE(2) alignment, RPE per scan (translation, rotation), failures (> 0.2 m or 5°),
  pairs/s.
- memory: peak RSS of `toolkit map` (load, match, trajectory, cloud, map.png, metrics) on a
  synthetic log of repeated simulated scans (1,000,000 scans; 100,000 with --quick).
- streaming: the one-scan-at-a-time matcher's working memory per pair and its largest
  difference from the batch poses.

Every measurement runs in a child process with OMP_NUM_THREADS=1 (Open3D's threads spin on a
shared 2-core machine and cost ICP 10-100x) and its own peak RSS.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bench import peak_rss_mb

if TYPE_CHECKING:
    from toolkit.dataset import Dataset

REAL = Path(
    os.environ.get(
        "TOOLKIT_REAL_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"
    )
)
CARMEN = ("intel", "acapulco", "fhw", "orebro", "edmonton", "freiburg-101", "seattle")
METHODS = ("odometry", "icp", "icp-point", "gaussian")  # numba's threads last (see child_speed)


def _child(*args: str, timeout: float = 3600) -> dict[str, Any] | list[dict[str, Any]]:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "TOOLKIT_NO_PROGRESS": "1"}
    result = subprocess.run(
        [sys.executable, "-m", "bench.bench_scanmatch", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
        cwd=Path(__file__).resolve().parents[1],
    )
    if result.returncode != 0:
        raise RuntimeError(f"bench child {args} failed: {result.stderr.strip()[-2000:]}")
    out: dict[str, Any] | list[dict[str, Any]] = json.loads(result.stdout.strip().splitlines()[-1])
    return out


def _child_row(*args: str) -> dict[str, Any]:
    """A child that prints one row."""
    out = _child(*args)
    assert isinstance(out, dict), f"bench child {args} printed {type(out).__name__}, not a row"
    return out


def _child_rows(*args: str) -> list[dict[str, Any]]:
    """A child that prints a list of rows."""
    out = _child(*args)
    assert isinstance(out, list), f"bench child {args} printed {type(out).__name__}, not rows"
    return out


# ---------------------------------------------------------------- children


def _dataset(name: str, work: Path) -> Dataset:
    import toolkit
    from toolkit.poses import with_drift

    if name in ("corridor", "building"):
        from toolkit.sim import simulate

        return simulate(name, seed=0).dataset
    import importers
    from importers.base import ImportOptions

    out = work / name
    if not out.exists():
        source = REAL / "carmen_radish_corrected" / f"{name}-corrected.log.gz"
        importers.import_log("carmen", [source], out, ImportOptions(extra={"poses": "groundtruth"}))
    return with_drift(toolkit.load(out), seed=0)


def child_speed(sample: int, repeats: int) -> list[dict[str, Any]]:
    import numba

    from toolkit import se2
    from toolkit.align import scan as sc
    from toolkit.align.baselines import match_pairs_icp
    from toolkit.poses import odometry_poses

    ds = _dataset("building", Path())
    odo = odometry_poses(ds)
    assert odo is not None
    seeds = se2.laser_motion(se2.between(odo[:-1], odo[1:]), ds.laser)
    pairs = len(seeds)
    rates: dict[str, float] = {}
    # ICP as the matcher is run: the same odometry seeds, its gate as the correspondence
    # distance, its cap on rounds (ICP converges within it here: 30 gave the same poses
    # ~10% slower)
    config = sc.MatchConfig()
    for method in ("point_to_line", "point_to_point"):
        match_pairs_icp(ds.ranges[:2], seeds[:1], ds.laser, method)
        times = []
        for r in range(max(1, repeats // 2)):
            lo = (r * sample) % (pairs - sample)
            t0 = time.perf_counter()
            match_pairs_icp(
                ds.ranges[lo : lo + sample + 1],
                seeds[lo : lo + sample],
                ds.laser,
                method,
                max_distance=config.gate,
                iterations=config.iterations,
            )
            times.append(time.perf_counter() - t0)
        rates[f"icp-{method}"] = sample / float(np.median(times))
    # the Gaussian matcher last: once numba's thread pool has run, Open3D's ICP slows 10-100x
    sc.match_pairs(ds.ranges[:3], seeds[:2], ds.laser)  # compile outside the timing
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sc.match_pairs(ds.ranges, seeds, ds.laser)
        times.append(time.perf_counter() - t0)
    rates["gaussian"] = pairs / float(np.median(times))
    # per core, as ICP runs (one pair at a time, one thread)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sc.match_pairs(ds.ranges, seeds, ds.laser)
        times.append(time.perf_counter() - t0)
    numba.set_num_threads(threads)
    rates["gaussian-1-thread"] = pairs / float(np.median(times))
    best_icp = max(rates["icp-point_to_line"], rates["icp-point_to_point"])
    return [
        {
            "table": "speed",
            "name": name,
            "log": "building (sim)",
            "beams": ds.n_beams,
            "pairs": pairs if name.startswith("gaussian") else sample,
            "pairs_per_s": rate,
            "gaussian_speedup": rates["gaussian"] / rate,
            "vs_best_icp": rate / best_icp if name.startswith("gaussian") else None,
            "threads": threads if name == "gaussian" else 1,
        }
        for name, rate in rates.items()
    ]


def child_accuracy(name: str, work: str) -> list[dict[str, Any]]:
    from toolkit.metrics import evaluate
    from toolkit.poses import build, truth_poses

    ds = _dataset(name, Path(work))
    truth = truth_poses(ds)
    assert truth is not None, f"{name} has no ground truth"
    assert ds.odometry is not None, f"{name} has no odometry"
    warm = ds.__class__(t=ds.t[:3], ranges=ds.ranges[:3], laser=ds.laser, odometry=ds.odometry[:3])
    rows = []
    for method in METHODS:
        build(warm, method)  # compile / start Open3D outside the timing
        result = build(ds, method)
        m = evaluate(result.poses, truth)
        rows.append(
            {
                "table": "accuracy",
                "name": method,
                "log": name,
                "scans": ds.n_scans,
                "beams": ds.n_beams,
                "ate_m": m["ate"]["rmse"],
                "rpe_m": m["rpe"]["translation"],
                "rpe_deg": m["rpe"]["rotation_deg"],
                "failures": m["failures"]["count"],
                "pairs_per_s": result.pairs_per_second,
            }
        )
    by = {r["name"]: r for r in rows}
    g, odo = by["gaussian"], by["odometry"]
    better_icp = min(by["icp"]["rpe_m"], by["icp-point"]["rpe_m"])
    better_icp_deg = min(by["icp"]["rpe_deg"], by["icp-point"]["rpe_deg"])
    g["rpe_m_vs_better_icp"] = g["rpe_m"] / better_icp
    g["rpe_deg_vs_better_icp"] = g["rpe_deg"] / better_icp_deg
    g["failures_le_icp"] = g["failures"] <= min(by["icp"]["failures"], by["icp-point"]["failures"])
    g["ate_vs_odometry"] = g["ate_m"] / odo["ate_m"]
    return rows


def child_make_log(scans: int, out: str) -> dict[str, Any]:
    """A long log: the simulated building's scans repeated, its path continued lap after lap."""

    import toolkit
    from toolkit import se2
    from toolkit.dataset import pose_frame
    from toolkit.poses import compose_steps

    base = _dataset("building", Path())
    laps = -(-scans // base.n_scans)
    ranges = np.tile(base.ranges, (laps, 1))[:scans]
    frames = {}
    for name, frame in (("odometry", base.odometry), ("groundtruth", base.groundtruth)):
        assert frame is not None, f"the simulation has no {name}"
        p = frame[["x", "y", "theta"]].to_numpy()
        steps = se2.between(p[:-1], p[1:])
        steps = np.concatenate([steps, np.zeros((1, 3))])  # lap to lap: no motion
        poses = compose_steps(p[0], np.tile(steps, (laps, 1))[: scans - 1])
        dt = float(np.median(np.diff(base.t)))
        t = base.t[0] + dt * np.arange(scans)
        frames[name] = pose_frame(t, poses)
    ds = toolkit.Dataset(
        t=frames["odometry"]["t"].to_numpy(),
        ranges=ranges,
        laser=base.laser,
        odometry=frames["odometry"],
        groundtruth=frames["groundtruth"],
        meta={"note": f"building simulation repeated to {scans} scans"},
    )
    toolkit.save(ds, out)
    return {"scans": scans}


def child_map(dataset: str, out: str, voxel: float) -> dict[str, Any]:
    from toolkit.mapping import map_run

    t0 = time.perf_counter()
    run = map_run(dataset, out, "gaussian", voxel).path
    seconds = time.perf_counter() - t0
    metrics = json.loads((run / "metrics.json").read_text())
    return {
        "seconds": seconds,
        "peak_rss_mb": peak_rss_mb(),
        "pairs_per_s": metrics["pairs_per_second"],
        "cloud_mb": (run / "cloud.ply").stat().st_size / 2**20,
    }


def child_stream() -> dict[str, Any]:
    from toolkit.align import scan as sc
    from toolkit.poses import build, odometry_poses

    ds = _dataset("corridor", Path())
    batch = build(ds, "gaussian").poses
    odo = odometry_poses(ds)
    assert odo is not None
    stream = sc.StreamMatcher(ds.laser)
    t0 = time.perf_counter()
    poses = np.array([stream.push(r, o) for r, o in zip(ds.ranges, odo, strict=True)])
    seconds = time.perf_counter() - t0
    return {
        "table": "streaming",
        "name": "gaussian-stream",
        "log": "corridor (sim)",
        "beams": ds.n_beams,
        "bytes_per_pair": stream.working_bytes,
        "max_pose_diff_vs_batch": float(np.abs(poses - batch).max()),
        "pairs_per_s": (len(poses) - 1) / seconds,
    }


# ---------------------------------------------------------------- the benchmark


def run(out: Path, quick: bool) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    rows += _child_rows("speed", "100" if quick else "400", "3" if quick else "9")
    logs = ["corridor", "building"] + [n for n in CARMEN[: 1 if quick else None]]
    with tempfile.TemporaryDirectory(dir=out) as work:
        for name in logs:
            if name in CARMEN and not (REAL / "carmen_radish_corrected").is_dir():
                continue
            rows += _child_rows("accuracy", name, work)
        scans = 100_000 if quick else 1_000_000
        log = Path(work) / "long"
        _child("make-log", str(scans), str(log))
        mem = _child_row("map", str(log), str(Path(work) / "run"), "0.1")
        rows.append({"table": "memory", "name": "toolkit map", "scans": scans, **mem})
    rows.append(_child_row("stream"))
    return rows


def main() -> None:
    what, *args = sys.argv[1:]
    result: Any
    if what == "speed":
        result = child_speed(int(args[0]), int(args[1]))
    elif what == "accuracy":
        result = child_accuracy(args[0], args[1])
    elif what == "make-log":
        result = child_make_log(int(args[0]), args[1])
    elif what == "map":
        result = child_map(args[0], args[1], float(args[2]))
    elif what == "stream":
        result = child_stream()
    else:
        raise SystemExit(f"unknown child {what!r}")
    print(json.dumps(result, default=float))


if __name__ == "__main__":
    main()
