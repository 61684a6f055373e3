"""Maps from a trajectory: the run directory that `toolkit map` writes.

The map is the union of every scan placed at its pose, m(t+1) = m(t) ∪ {l(t), s(t)} (paper
Eq. 2). The 3D cloud puts each return at its world position and the laser's mounting height,
coloured by time. Everything is done in chunks of scans, so a log of a million scans maps
in bounded memory: the cloud is streamed to a binary PLY and PCD (or voxel-downsampled chunk
by chunk), and map.png is the returns counted into a pixel grid chunk by chunk. The writers
are numpy (`toolkit.writers`) and numba kernels that place each return once (the cloud's
vertices here, the map's counts in `toolkit.raster`): no plotting or 3D library is loaded.
They run side by side in threads (`map_run`).

RUN/
    config.json          what was run: dataset, method, matcher parameters, voxel size
    trajectory.parquet   t, x, y, theta per scan (robot frame, world coordinates)
    trajectory.tum       the same in TUM format (t x y z qx qy qz qw), for evo
    groundtruth.tum      the ground truth at the scan times, when the dataset has one
    cloud.ply            the 3D map: x y z, red green blue (by time), t, scan per vertex
    cloud.pcd            the same as a binary PCD (PCL's packed rgb)
    map.png              the 2D map with the trajectory (resolution and origin in its text)
    metrics.json         ATE, RPE, failures (with ground truth), time aligning, pairs/s, and
                         `seconds`: the time of every stage (read, match, compose, writers)
"""

from __future__ import annotations

import datetime as _dt
import importlib
import json
import math
import time
from collections.abc import Callable, Collection
from concurrent.futures import Future
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

import numba as nb
import numpy as np
import pyarrow.parquet as pq

from toolkit.align import scan as sc
from toolkit.atomic import atomic_dir, check_output, writer_threads
from toolkit.beams import fixed_beams, share_beyond_reach, without_beams
from toolkit.dataset import META, ODOMETRY, Dataset, load, sha256, write_described
from toolkit.errors import ToolkitError
from toolkit.metrics import evaluate
from toolkit.mounting import Mounting, mounting
from toolkit.poses import (
    ICP_METHODS,
    Method,
    TrajectoryResult,
    build,
    icp_settings,
    odometry_poses,
    truth_poses,
)
from toolkit.progress import counted
from toolkit.raster import BeamFrame, beam_frame, return_xy, scan_chunks, write_map_png
from toolkit.raster import world_points as world_points  # re-exported: the cloud's arithmetic
from toolkit.slam.relations import relation_metrics
from toolkit.slam.render import write_occupancy, write_side_by_side
from toolkit.slam.stalls import Stall, mend_stalls, still_stretches
from toolkit.writers import (
    CLOUD,
    PCD,
    VIRIDIS_LUT,
    pcd_header,
    ply_header,
    write_pcd,
    write_ply,
)

if TYPE_CHECKING:
    from toolkit.slam.pipeline import SlamConfig
    from toolkit.slam.run import SlamRun

# scans per chunk of the cloud writers: ~2.5 MB of vertices at 361 beams, in two buffers
# filled again chunk after chunk (`write_clouds`). The bytes cost what fresh memory costs:
# 2,000 scans a chunk (~40 MB of fresh pages for the buffers) made the clouds 0.25-0.3 s of
# CPU on a 5,000 x 361 log in a new process, 256 scans 0.04-0.07 s (docs/benchmarks.md,
# session 15); 100 or 500 about the same
CLOUD_CHUNK = 256

#: Threads that write a run's outputs side by side (`map_run`): the clouds, map.png and the
#: occupancy grid, the three long ones, each on its own.
WRITER_THREADS = 3


def cloud_rows(
    ds: Dataset, robot: np.ndarray, part: slice, t_span: tuple[float, float]
) -> np.ndarray:
    """The returns of scans `part` as cloud vertices (`toolkit.writers.CLOUD`): world x, y,
    the laser's height, viridis by time over `t_span`, the scan's time and index."""
    return cloud_chunk(ds, robot, part, t_span, pcd=False)[0]


def cloud_chunk(
    ds: Dataset,
    robot: np.ndarray,
    part: slice,
    t_span: tuple[float, float],
    pcd: bool = True,
    out: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The returns of scans `part` as PLY vertices (`cloud_rows`) and, with `pcd`, as PCD
    points (`toolkit.writers.PCD`; else an empty array), filled in one pass by a numba kernel:
    the positions by `world_points`' arithmetic and the colour by `viridis`' (the same
    bytes as those numpy functions give, without their N x 2 and N x 3 temporaries). `out`:
    CLOUD and PCD buffers to fill (their first rows; the PCD one may be empty without
    `pcd`), returned as views of the rows filled, instead of new arrays."""
    ranges = ds.ranges[part]
    n = int(np.count_nonzero(np.isfinite(ranges)))
    if out is None:
        ply = np.empty(n, CLOUD)
        points = np.empty(n if pcd else 0, PCD)
    else:
        ply, points = out[0][:n], out[1][: n if pcd else 0]
    t0, t1 = t_span
    _cloud_vertices(
        ranges, beam_frame(robot[part], ds.laser), float(ds.laser.z), ds.t[part], t0,
        t1 - t0 if t1 > t0 else 1.0, VIRIDIS_LUT, part.start or 0, ply, points, pcd,
    )  # fmt: skip
    return ply, points


@nb.njit(cache=True, nogil=True)
def _cloud_vertices(
    ranges: np.ndarray,
    frame: BeamFrame,
    z: float,
    t: np.ndarray,
    t0: float,
    span: float,
    lut: np.ndarray,
    first: int,
    ply: np.ndarray,
    pcd: np.ndarray,
    with_pcd: bool,
) -> None:
    """Fill `ply` (CLOUD) and, `with_pcd`, `pcd` (PCD) with the finite returns of `ranges`
    in row order; see `cloud_chunk`."""
    zf = np.float32(z)
    n = 0
    for k in range(ranges.shape[0]):
        index = (t[k] - t0) / span * 255.0 + 0.5  # viridis: clip, then truncate
        index = 0.0 if index < 0.0 else (255.0 if index > 255.0 else index)
        q = int(index)
        red, green, blue = lut[q, 0], lut[q, 1], lut[q, 2]
        rgb = (np.uint32(red) << 16) | (np.uint32(green) << 8) | np.uint32(blue)
        for b in range(ranges.shape[1]):
            r = np.float64(ranges[k, b])
            if not math.isfinite(r):
                continue
            wx, wy = return_xy(frame, k, b, r)
            x, y = np.float32(wx), np.float32(wy)
            v = ply[n]
            v.x, v.y, v.z, v.t, v.scan = x, y, zf, t[k], first + k
            v.red, v.green, v.blue = red, green, blue
            if with_pcd:
                p = pcd[n]
                p.x, p.y, p.z, p.rgb, p.t, p.scan = x, y, zf, rgb, t[k], first + k
            n += 1


def voxel_down(rows: np.ndarray, voxel: float) -> np.ndarray:
    """One vertex per occupied voxel of side `voxel`: the mean position, colour and time of its
    vertices and the first (earliest) scan's index, in voxel order."""
    if len(rows) == 0:
        return rows
    cell = np.column_stack([np.floor(rows[a] / voxel) for a in ("x", "y", "z")]).astype(np.int64)
    cell -= cell.min(axis=0)
    span = cell.max(axis=0) + 1
    key = (cell[:, 0] * span[1] + cell[:, 1]) * span[2] + cell[:, 2]
    _, inverse, count = np.unique(key, return_inverse=True, return_counts=True)
    out = np.empty(len(count), CLOUD)
    for name in ("x", "y", "z", "t", "red", "green", "blue"):
        mean = np.bincount(inverse, weights=rows[name].astype(np.float64)) / count
        out[name] = np.round(mean) if out.dtype[name].kind == "u" else mean
    grouped = rows["scan"][np.argsort(inverse, kind="stable")]  # voxel by voxel
    out["scan"] = np.minimum.reduceat(grouped, np.concatenate([[0], np.cumsum(count)[:-1]]))
    return out


def write_clouds(
    paths: list[Path],
    ds: Dataset,
    robot: np.ndarray,
    voxel: float = 0.0,
    chunk: int = CLOUD_CHUNK,
) -> int:
    """The 3D map to each of `paths` (a binary PLY, or a binary PCD for a .pcd path), the points
    computed once: every return at its world x, y and the laser's height, coloured by time
    (viridis), with its scan's time `t` and index `scan` as properties. Returns the number of
    points written. Without `voxel` the returns are streamed chunk by chunk of scans (memory
    does not grow with the log); with `voxel` > 0 each chunk is reduced to one point per voxel
    (the mean) and then their union again."""
    kinds = [Path(p).suffix.lower() == ".pcd" for p in paths]
    span = (float(ds.t[0]), float(ds.t[-1])) if len(ds.t) else (0.0, 1.0)
    if voxel > 0:
        merged = np.empty(0, CLOUD)
        for part in scan_chunks(ds.n_scans, chunk):
            down = voxel_down(cloud_rows(ds, robot, part, span), voxel)
            merged = voxel_down(np.concatenate([merged, down]), voxel)
        for path, pcd in zip(paths, kinds, strict=True):
            with open(path, "wb") as f:
                (write_pcd if pcd else write_ply)(f, merged)
        return len(merged)
    counts = [
        int(np.count_nonzero(np.isfinite(ds.ranges[p]))) for p in scan_chunks(ds.n_scans, chunk)
    ]
    total = sum(counts)
    # one pair of buffers for every chunk: their pages are touched once and stay in cache
    most = max(counts, default=0)
    buffers = (np.empty(most, CLOUD), np.empty(most if any(kinds) else 0, PCD))
    with ExitStack() as stack:
        files = [stack.enter_context(open(p, "wb")) for p in paths]
        for f, pcd in zip(files, kinds, strict=True):
            f.write(pcd_header(total) if pcd else ply_header(total))
        for part in scan_chunks(ds.n_scans, chunk):
            rows, points = cloud_chunk(ds, robot, part, span, pcd=any(kinds), out=buffers)
            for f, pcd in zip(files, kinds, strict=True):
                (points if pcd else rows).tofile(f)
    return total


TUM_BLOCK = 8192  # rows formatted per call


def write_tum(path: Path, t: np.ndarray, poses: np.ndarray) -> None:
    """TUM trajectory format, one line per pose: t x y z qx qy qz qw (z = 0, yaw only)."""
    half = poses[:, 2] / 2
    zero = np.zeros(len(t))
    table = np.column_stack(
        [t, poses[:, 0], poses[:, 1], zero, zero, zero, np.sin(half), np.cos(half)]
    )
    # np.savetxt's bytes (each row `fmt % tuple(row)`), formatted one block of rows per call
    # rather than a Python loop over rows (5,000 rows 0.05 -> 0.01 s, with the GIL the other
    # writers need); blocks keep the formatted text small on a million-scan log
    row = " ".join(["%.6f"] + ["%.9f"] * 7) + "\n"
    with open(path, "w") as f:
        for start in range(0, len(table), TUM_BLOCK):
            block = table[start : start + TUM_BLOCK]
            f.write((row * len(block)) % tuple(block.ravel()))


def run_metrics(ds: Dataset, result: TrajectoryResult) -> dict[str, Any]:
    """metrics.json: timing always; ATE/RPE/failures (and odometry's, for scale) with truth."""
    out: dict[str, Any] = {
        "method": result.method,
        "scans": ds.n_scans,
        "pairs": len(result.matches) if result.matches is not None else 0,
        "seconds_aligning": result.seconds,
        "pairs_per_second": result.pairs_per_second,
    }
    if result.matches is not None and result.method == Method.GAUSSIAN:
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
    if odo is not None and result.method != Method.ODOMETRY:
        out["odometry"] = evaluate(odo, truth)
    return out


def _meta_digest(ds: Dataset) -> str | None:
    """sha256 of the dataset's meta.json (its identity: sources' sha256, import time), so a
    re-run can tell an unchanged dataset (`toolkit.app.fleet_map.run_is_current`)."""
    meta = ds.path / META if ds.path else None
    return sha256(meta) if meta is not None and meta.is_file() else None


#: The sequential matcher a run uses (`matcher_of`): scan-to-map's (`slam.scan_map`,
#: `MapConfig`), the pair matcher's (`MatchConfig`), ICP's (of `MatchConfig` only its
#: keyframes) or none (odometry).
SCAN_TO_MAP, PAIRS, ICP = "scan-to-map", "pairs", "icp"


#: A run's expert settings: the pair matcher's and the mapper's (None: the defaults).
Settings: TypeAlias = tuple["sc.MatchConfig | None", "SlamConfig | None"]


def matcher_of(
    method: Method | str,
    loops: bool = True,
    slam_config: SlamConfig | None = None,
    odometry: bool = True,
) -> str | None:
    """Which sequential matcher maps a dataset with `odometry` or not by these settings:
    scan-to-map with loops where `SlamConfig.maps_scan_to_map` (as `slam_trajectory` decides
    it), else the pair matcher (ICP's for icp); None by odometry."""
    method = Method.parse(method)
    if method == Method.ODOMETRY:
        return None
    if method in ICP_METHODS:
        return ICP
    if not loops:
        return PAIRS
    from toolkit.slam.pipeline import SlamConfig  # noqa: PLC0415 (on use: the mapper)

    mapper = slam_config or SlamConfig()
    return SCAN_TO_MAP if mapper.maps_scan_to_map(method, odometry) else PAIRS


def has_odometry(dataset: Path) -> bool:
    """Whether the dataset directory has odometry (rows in odometry.parquet; its footer only),
    which decides the mapper's front end and so its matcher (`matcher_of`)."""
    path = dataset / ODOMETRY
    return path.is_file() and pq.ParquetFile(path).metadata.num_rows > 0


def recorded_settings(
    method: Method | str,
    loops: bool = True,
    config: sc.MatchConfig | None = None,
    slam_config: SlamConfig | None = None,
    odometry: bool = True,
) -> dict[str, Any]:
    """config.json's "matcher" and "slam" as `map_run` records them for these settings on a
    dataset with `odometry` or not, JSON-shaped (tuples as lists): what a run of them reads
    back, so that a fleet's re-run can tell a run of other settings (`run_is_current`).

    As `slam_trajectory` and `build` record them (`matcher_of`): the scan-to-map matcher's
    (`slam.scan_map`) with loops, gaussian, the "map" front end and odometry; else the pair
    matcher's (`config`; ICP's own), and then the mapper's front end is the keyframe one;
    nothing by odometry. (A dataset of fewer than two scans records no matcher: never current.)"""
    method = Method.parse(method)
    config = config or sc.MatchConfig()
    pairs = icp_settings(method, config) if method in ICP_METHODS else config.to_dict()
    matcher: dict[str, object] = {} if method == Method.ODOMETRY else pairs
    slam: dict[str, Any] | None = None
    if loops and method != Method.ODOMETRY:
        # on use, as map_run loads the mapper: with loops only
        from toolkit.slam.pipeline import SlamConfig  # noqa: PLC0415
        from toolkit.slam.scanmap import settings as scan_map_settings  # noqa: PLC0415

        mapper = slam_config or SlamConfig()
        if matcher_of(method, loops, mapper, odometry) == SCAN_TO_MAP:
            matcher = scan_map_settings(mapper.scan_map)
        else:
            mapper = replace(mapper, front_end="keyframe")
        slam = mapper.to_dict()
    recorded: dict[str, Any] = json.loads(json.dumps({"matcher": matcher, "slam": slam}))
    return recorded


#: `toolkit map`'s bars: the scan pairs matched, and these steps: loops and pose graph (or
#: composition), trajectory files and clouds, maps, metrics.
MAP_STEPS = 4

#: Every file of a run directory; `map_run(outputs=...)` writes a subset (the report, which
#: draws its own maps, leaves out the clouds and the maps). graph.g2o and loops.csv come with
#: loop closure, groundtruth.tum with ground truth.
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
    method: Method | str = Method.GAUSSIAN,
    voxel: float = 0.0,
    config: sc.MatchConfig | None = None,
    force: bool = False,
    matcher: Callable[..., sc.PairMatches] | None = None,
    loops: bool = True,
    outputs: Collection[str] = OUTPUTS,
    slam_config: SlamConfig | None = None,
) -> MapRun:
    """`toolkit map`: align `dataset` (loaded if a path) by `method` and write the run
    directory `out` atomically: `outputs` of OUTPUTS ("cloud.ply" brings cloud.pcd, "map.png"
    the occupancy grid map.pgm + map.yaml). With `loops`, the mapper's loop closure and pose
    graph (`toolkit.slam.run`: graph.g2o, loops.csv), by `slam_config`'s settings
    (None: the defaults). `matcher`: see `toolkit.poses.build`.
    metrics.json's `seconds` holds the time of every stage: read, the trajectory's (prepare,
    compile, match, compose, and the loops'), and each output's by file name. The CLI, the
    fleet, the bench and the report all map through here."""
    out = Path(out)
    check_output(out, force)
    unknown = set(outputs) - set(OUTPUTS)
    if unknown:
        raise ToolkitError(f"unknown run outputs {sorted(unknown)}; known: {', '.join(OUTPUTS)}")
    t0 = time.perf_counter()
    ds = dataset if isinstance(dataset, Dataset) else load(dataset)
    timed = {"read": time.perf_counter() - t0} if not isinstance(dataset, Dataset) else {}
    config = config or sc.MatchConfig()
    method = Method.parse(method)
    # the scans' own checks, when they are matched: beams that read the robot itself would
    # hold every match still; ranges beyond any laser's reach (cm or mm) match nothing
    matched_scans = method != Method.ODOMETRY
    fixed = np.empty(0, dtype=np.int64)
    wheels = odometry_poses(ds) if matched_scans else None
    mount: Mounting | None = None
    if matched_scans:
        fixed = fixed_beams(ds.ranges, wheels)  # without odometry: from scans far apart
        ds = without_beams(ds, fixed)
    if wheels is not None:
        # a laser turned round or upside down against what the log says fights the odometry
        # in every match: read as the scans and the odometry agree it is mounted
        mount = mounting(ds.ranges, wheels, ds.laser)
        if mount.changed:
            ds = replace(ds, laser=mount.laser(ds.laser))
    beyond_reach = share_beyond_reach(ds.ranges) if matched_scans else 0.0
    # odometry that stood still while the scans moved (a stalled encoder, a stream that
    # starts late or stops early) is mended from the scans for the matching (each still
    # stretch mapped first, counted with the pairs); the outputs and metrics keep the
    # odometry as logged
    stretches = still_stretches(wheels) if wheels is not None else []
    pairs = max(ds.n_scans - 1, 0) if matched_scans else 0
    pairs += sum(last - first for first, last in stretches)
    steps = "loops, outputs" if loops and matched_scans else "outputs"
    with counted(f"map ({method})", pairs, "scan pairs", steps, MAP_STEPS) as (matched, step):
        matched_ds, stalls = ds, list[Stall]()
        if wheels is not None:
            matched_ds, stalls = mend_stalls(ds, wheels, stretches, config, slam_config, matched)
        slam: SlamRun | None = None
        if loops and method != Method.ODOMETRY:
            # on use: loop closure and the pose graph load GTSAM and scipy.ndimage
            slam_run = importlib.import_module("toolkit.slam.run")
            result, slam = slam_run.slam_trajectory(
                matched_ds, method, config, matcher, slam_config, progress=matched
            )
        else:
            result = build(matched_ds, method, config, matcher, progress=matched)
        timed |= result.timings
        step()
        robot = result.poses
        truth = truth_poses(ds)
        with atomic_dir(out, force=force) as tmp, writer_threads(WRITER_THREADS) as pool:
            # the outputs are written side by side in threads (the clouds, the map and the
            # occupancy grid spend their time in numpy, zlib, file writes and a nogil numba
            # kernel, which release the GIL); metrics are computed here meanwhile. Every writer
            # has ended before atomic_dir commits or cleans up, even if a stop lands in the wait.
            writers: dict[str, Future[float]] = {}
            grid: dict[str, Any] = {}  # the occupancy grid's consistency, once it is written
            t_outputs = time.perf_counter()

            def timing(name: str, write: Callable[[Path], object]) -> None:
                def timed_write() -> float:
                    t0 = time.perf_counter()
                    write(tmp / name)
                    return time.perf_counter() - t0

                writers[name] = pool.submit(timed_write)

            def finish(names: Collection[str]) -> None:
                """Wait for the writers `names` (the first failure raises) and time them."""
                for name in [n for n in writers if n in names]:
                    timed[name] = writers[name].result()

            settings = {
                "dataset": str(ds.path) if ds.path else None,
                "dataset_meta_sha256": _meta_digest(ds),
                "method": method,
                "voxel": voxel,
                "matcher": result.config,
                "slam": slam.config.to_dict() if slam is not None else None,
                "laser": ds.laser.to_dict(),
                "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            }
            if "config.json" in outputs:
                (tmp / "config.json").write_text(json.dumps(settings, indent=2) + "\n")
            if "cloud.ply" in outputs:  # the longest writers first
                clouds = [tmp / "cloud.ply", tmp / "cloud.pcd"]
                timing("cloud.ply+pcd", lambda _: write_clouds(clouds, ds, robot, voxel))
            name = ds.path.name if ds.path else "dataset"
            if "map.png" in outputs:
                title = f"{name}: {method} with loops" if slam is not None else f"{name}: {method}"
                if slam is not None:  # odometry / before loops / after loops side by side
                    panels = [("before loops", slam.before), ("after loops", robot)]
                    odo = odometry_poses(ds)
                    panels = [("odometry", odo), *panels] if odo is not None else panels
                    timing("map.png", lambda p: write_side_by_side(p, ds, panels, truth, title))
                else:
                    timing("map.png", lambda p: write_map_png(p, ds, robot, truth, title))
                timing("map.pgm+yaml", lambda _: grid.update(write_occupancy(tmp, ds, robot)[1]))
            if slam is not None:  # the graph and the loops always
                timing("graph.g2o+loops.csv", lambda _: slam.write(tmp, ds, robot, "", False))
            if "trajectory.parquet" in outputs:
                timing(
                    "trajectory.parquet",
                    lambda p: write_described(
                        p, result.stream.table(), "trajectory", method=method
                    ),
                )
            if "trajectory.tum" in outputs:
                timing("trajectory.tum", lambda p: write_tum(p, ds.t, robot))
            if truth is not None and "groundtruth.tum" in outputs:
                timing("groundtruth.tum", lambda p: write_tum(p, ds.t, truth))
            t0 = time.perf_counter()
            metrics = run_metrics(ds, result)
            if len(fixed):
                metrics["fixed_beams"] = fixed.tolist()
            if mount is not None and mount.changed:
                metrics["laser_mounting"] = {"read_as": mount.describe(), **mount.to_dict()}
            if stalls:
                metrics["odometry_stalls"] = [stall.to_dict() for stall in stalls]
            if beyond_reach > 0.5:  # nothing matched: the map is the odometry's
                metrics["beyond_reach"] = round(beyond_reach, 3)
            metrics["relation_error"] = relation_metrics(ds, robot)
            metrics |= slam.metrics(ds) if slam is not None else {}
            measuring = time.perf_counter() - t0
            finish(["trajectory.parquet", "trajectory.tum", "groundtruth.tum", "cloud.ply+pcd"])
            step()
            finish(["map.png", "map.pgm+yaml", "graph.g2o+loops.csv"])
            if grid:
                metrics["consistency"] = grid
            step()
            timed["metrics"] = measuring
            timed["outputs"] = time.perf_counter() - t_outputs  # the writers' and metrics' wall
            timed |= metrics.get("seconds", {})  # the loop closure's stages
            metrics["seconds"] = {k: round(v, 4) for k, v in timed.items()}
            if "metrics.json" in outputs:
                text = json.dumps(metrics, indent=2, allow_nan=False) + "\n"
                (tmp / "metrics.json").write_text(text)
            step()
    return MapRun(out, result, metrics)
