"""Maps from a trajectory: the run directory that `toolkit map` writes.

The map is the union of every scan placed at its pose, m(t+1) = m(t) ∪ {l(t), s(t)} (paper
Eq. 2). The 3D cloud puts each return at its world position and the laser's mounting height,
coloured by time. Everything is done in chunks of scans, so a log of a million scans maps
in bounded memory: the cloud is streamed to a binary PLY (or voxel-downsampled chunk by
chunk with Open3D), and map.png is a histogram of returns accumulated chunk by chunk.

RUN/
    config.json          what was run: dataset, method, matcher parameters, voxel size
    trajectory.parquet   t, x, y, theta per scan (robot frame, world coordinates)
    trajectory.tum       the same in TUM format (t x y z qx qy qz qw), for evo
    groundtruth.tum      the ground truth at the scan times, when the dataset has one
    cloud.ply            the 3D map
    map.png              the 2D map with the trajectory
    metrics.json         ATE, RPE, failures (with ground truth), time aligning, pairs/s
"""

from __future__ import annotations

import datetime as _dt
import json
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from toolkit.align import scan as sc
from toolkit.atomic import atomic_dir, check_output
from toolkit.dataset import Dataset, LaserGeometry, load
from toolkit.errors import ToolkitError
from toolkit.metrics import evaluate
from toolkit.poses import TrajectoryResult, build, odometry_poses, truth_poses

CHUNK = 20_000  # scans per chunk of map building


def laser_poses(robot: np.ndarray, laser: LaserGeometry) -> np.ndarray:
    """World poses of the laser (S x 3) for robot poses (S x 3)."""
    return sc.compose(robot, np.broadcast_to(sc.mount_pose(laser), robot.shape))


def world_points(
    ranges: np.ndarray, robot: np.ndarray, laser: LaserGeometry
) -> tuple[np.ndarray, np.ndarray]:
    """Every return of `ranges` (S x B) in world x, y (N x 2) and the scan it came from (N,)."""
    lp = laser_poses(robot, laser)
    scan, beam = np.nonzero(np.isfinite(ranges))
    r = ranges[scan, beam].astype(np.float64)
    bearing = lp[scan, 2] + laser.angles[beam]
    xy = np.column_stack([lp[scan, 0] + r * np.cos(bearing), lp[scan, 1] + r * np.sin(bearing)])
    return xy, scan


def _chunks(n: int, chunk: int) -> Iterator[slice]:
    for lo in range(0, n, chunk):
        yield slice(lo, min(lo + chunk, n))


def _colours(t: np.ndarray, t0: float, t1: float) -> np.ndarray:
    from matplotlib import colormaps

    span = t1 - t0 if t1 > t0 else 1.0
    rgba = colormaps["viridis"]((t - t0) / span)
    return np.asarray(rgba[:, :3])


def write_cloud(
    path: Path,
    ds: Dataset,
    robot: np.ndarray,
    voxel: float = 0.0,
    chunk: int = CHUNK,
) -> int:
    """The 3D map as a PLY: returns at world x, y and the laser's height z, coloured by time.

    With `voxel` > 0, Open3D voxel-downsamples each chunk and then their union; without, every
    return is streamed to a binary PLY (float x, y, z; uchar red, green, blue), which Open3D
    and other readers load. Returns the number of points written.
    """
    t0, t1 = (float(ds.t[0]), float(ds.t[-1])) if len(ds.t) else (0.0, 1.0)
    z = float(ds.laser.z)
    if voxel > 0:
        import open3d as o3d

        merged = o3d.geometry.PointCloud()
        for part in _chunks(ds.n_scans, chunk):
            xy, scan = world_points(ds.ranges[part], robot[part], ds.laser)
            cloud = o3d.geometry.PointCloud(
                o3d.utility.Vector3dVector(np.column_stack([xy, np.full(len(xy), z)]))
            )
            cloud.colors = o3d.utility.Vector3dVector(_colours(ds.t[part][scan], t0, t1))
            merged += cloud.voxel_down_sample(voxel)
            merged = merged.voxel_down_sample(voxel)
        o3d.io.write_point_cloud(str(path), merged, write_ascii=False)
        return len(merged.points)
    total = int(sum(np.isfinite(ds.ranges[p]).sum() for p in _chunks(ds.n_scans, chunk)))
    vertex = np.dtype(
        [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    )
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment laser-toolkit map\n"
        f"element vertex {total}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        for part in _chunks(ds.n_scans, chunk):
            xy, scan = world_points(ds.ranges[part], robot[part], ds.laser)
            rows = np.empty(len(xy), dtype=vertex)
            rows["x"], rows["y"], rows["z"] = xy[:, 0], xy[:, 1], z
            rgb = np.round(_colours(ds.t[part][scan], t0, t1) * 255).astype(np.uint8)
            rows["red"], rows["green"], rows["blue"] = rgb.T
            f.write(rows.tobytes())
    return total


def write_tum(path: Path, t: np.ndarray, poses: np.ndarray) -> None:
    """TUM trajectory format, one line per pose: t x y z qx qy qz qw (z = 0, yaw only)."""
    half = poses[:, 2] / 2
    zero = np.zeros(len(t))
    table = np.column_stack(
        [t, poses[:, 0], poses[:, 1], zero, zero, zero, np.sin(half), np.cos(half)]
    )
    np.savetxt(path, table, fmt=["%.6f"] + ["%.9f"] * 7, delimiter=" ")


def write_map_png(
    path: Path,
    ds: Dataset,
    robot: np.ndarray,
    truth: np.ndarray | None = None,
    title: str = "",
    chunk: int = CHUNK,
    cells: int = 1500,
) -> None:
    """Top view: a log-scaled histogram of every return, the trajectory over it (and the
    ground truth, dashed). Accumulated chunk by chunk: memory does not grow with the log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lo = np.array([np.inf, np.inf])
    hi = -lo
    for part in _chunks(ds.n_scans, chunk):
        xy, _ = world_points(ds.ranges[part], robot[part], ds.laser)
        if len(xy):
            lo = np.minimum(lo, np.percentile(xy, 0.5, axis=0))
            hi = np.maximum(hi, np.percentile(xy, 99.5, axis=0))
    lo = np.minimum(lo, robot[:, :2].min(axis=0) - 1) if len(robot) else lo
    hi = np.maximum(hi, robot[:, :2].max(axis=0) + 1) if len(robot) else hi
    if not np.isfinite(lo).all():
        lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    cell = max(float((hi - lo).max()) / cells, 0.02)
    shape = np.maximum(np.ceil((hi - lo) / cell).astype(int), 1)
    grid = np.zeros(shape, dtype=np.float64)
    for part in _chunks(ds.n_scans, chunk):
        xy, _ = world_points(ds.ranges[part], robot[part], ds.laser)
        ij = np.floor((xy - lo) / cell).astype(np.int64)
        inside = ((ij >= 0) & (ij < shape)).all(axis=1)
        np.add.at(grid, (ij[inside, 0], ij[inside, 1]), 1.0)
    fig, ax = plt.subplots(figsize=(8, 8 * shape[1] / max(shape[0], 1) + 0.5), dpi=120)
    extent = (lo[0], lo[0] + shape[0] * cell, lo[1], lo[1] + shape[1] * cell)
    shade = np.log1p(grid.T)
    top = float(np.percentile(shade[shade > 0], 95)) if (shade > 0).any() else 1.0
    ax.imshow(
        shade, origin="lower", extent=extent, cmap="Greys", vmin=0, vmax=top, interpolation="none"
    )
    if truth is not None:
        ax.plot(truth[:, 0], truth[:, 1], "--", color="tab:green", lw=0.8, label="ground truth")
    ax.plot(robot[:, 0], robot[:, 1], color="tab:red", lw=0.8, label="trajectory")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.set_title(title)
    ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def run_metrics(ds: Dataset, result: TrajectoryResult) -> dict[str, Any]:
    """metrics.json: timing always; ATE/RPE/failures (and odometry's, for scale) with truth."""
    out: dict[str, Any] = {
        "method": result.method,
        "scans": ds.n_scans,
        "pairs": len(result.matches) if result.matches is not None else 0,
        "seconds_aligning": result.seconds,
        "pairs_per_second": result.pairs_per_second,
    }
    if result.matches is not None and result.method == "gaussian":
        out["degenerate_pairs"] = {
            "one_direction_from_odometry": int((result.matches.degenerate == 1).sum()),
            "all_from_odometry": int((result.matches.degenerate == 2).sum()),
        }
    truth = truth_poses(ds)
    if truth is None:
        out["groundtruth"] = False
        return out
    out["groundtruth"] = True
    out.update(evaluate(result.poses, truth))
    odo = odometry_poses(ds)
    if odo is not None and result.method != "odometry":
        out["odometry"] = evaluate(odo, truth)
    return out


def _meta_digest(ds: Dataset) -> str | None:
    """sha256 of the dataset's meta.json (its identity: sources' sha256, import time), so a
    re-run can tell an unchanged dataset (`toolkit.app.fleet.run_is_current`)."""
    from toolkit.dataset import META, sha256

    meta = ds.path / META if ds.path else None
    return sha256(meta) if meta is not None and meta.is_file() else None


#: Every file of a run directory; `map_run(outputs=...)` writes a subset (the report, which
#: draws its own maps, leaves out cloud.ply and map.png).
OUTPUTS = (
    "config.json",
    "trajectory.parquet",
    "trajectory.tum",
    "groundtruth.tum",
    "cloud.ply",
    "map.png",
    "metrics.json",
)


@dataclass
class MapRun:
    """A run directory and what was computed for it (the trajectory, timed, and metrics.json)."""

    path: Path
    result: TrajectoryResult
    metrics: dict[str, Any]


def map_run(
    dataset: Dataset | str | Path,
    out: str | Path,
    method: str = "gaussian",
    voxel: float = 0.0,
    config: sc.MatchConfig | None = None,
    force: bool = False,
    matcher: Callable[..., sc.PairMatches] | None = None,
    outputs: Collection[str] = OUTPUTS,
) -> MapRun:
    """`toolkit map`: align `dataset` (loaded if a path) by `method` and write the run
    directory `out` atomically: `outputs` of OUTPUTS (groundtruth.tum only when the dataset
    has ground truth). `matcher`: see `toolkit.poses.build`. The CLI, the fleet, the bench
    and the report all map through here."""
    out = Path(out)
    check_output(out, force)
    unknown = set(outputs) - set(OUTPUTS)
    if unknown:
        raise ToolkitError(f"unknown run outputs {sorted(unknown)}; known: {', '.join(OUTPUTS)}")
    ds = dataset if isinstance(dataset, Dataset) else load(dataset)
    config = config or sc.MatchConfig()
    from toolkit.progress import task

    with task(f"map ({method})", 4) as (progress, bar):
        result = build(ds, method, config, matcher)
        progress.advance(bar)
        robot = result.poses
        truth = truth_poses(ds)
        with atomic_dir(out, force=force) as tmp:
            settings = {
                "dataset": str(ds.path) if ds.path else None,
                "dataset_meta_sha256": _meta_digest(ds),
                "method": method,
                "voxel": voxel,
                "matcher": result.config,
                "laser": ds.laser.to_dict(),
                "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            }
            if "config.json" in outputs:
                (tmp / "config.json").write_text(json.dumps(settings, indent=2) + "\n")
            if "trajectory.parquet" in outputs:
                result.frame.to_parquet(tmp / "trajectory.parquet", index=False)
            if "trajectory.tum" in outputs:
                write_tum(tmp / "trajectory.tum", ds.t, robot)
            if truth is not None and "groundtruth.tum" in outputs:
                write_tum(tmp / "groundtruth.tum", ds.t, truth)
            if "cloud.ply" in outputs:
                write_cloud(tmp / "cloud.ply", ds, robot, voxel)
            progress.advance(bar)
            if "map.png" in outputs:
                name = ds.path.name if ds.path else "dataset"
                write_map_png(tmp / "map.png", ds, robot, truth, f"{name}: {method}")
            progress.advance(bar)
            metrics = run_metrics(ds, result)
            if "metrics.json" in outputs:
                text = json.dumps(metrics, indent=2, allow_nan=False) + "\n"
                (tmp / "metrics.json").write_text(text)
            progress.advance(bar)
    return MapRun(out, result, metrics)


def read_trajectory(path: str | Path) -> pd.DataFrame:
    """A run's trajectory.parquet."""
    return pd.read_parquet(path)
