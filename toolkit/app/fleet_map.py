"""Scale out on Dask: the same matching on a cluster of worker processes, bit for bit.

    with client_for("local:4") as client:             # None in-process, or a Dask Client
        matches = match_pairs_on(client, ranges, seeds, laser, config, ref, scans=path)

The pair list (reference keyframe and seed of every scan, from odometry) is known before any
matching, so a long log is cut into chunks of consecutive pairs: chunk k holds the pairs whose
current scans are row group k of scans.parquet (`ROW_GROUP_SCANS`). A chunk's task gets the
scans before it that its pairs use as references (the overlap: one scan, the keyframe or the
previous scan), its seeds and its own scans: shipped by the client, or read by the worker
from the dataset's scans.parquet on shared storage. The worker matches them with
`toolkit.align.scan.match_pairs` and the chunks' relative poses are gathered in order. Every
pair is matched by the same kernel from the same inputs wherever it runs, so the composed
trajectory equals the single-process run exactly. Many datasets (`map_many`) run one task
each.
"""

from __future__ import annotations

import itertools
import json
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numba
import numpy as np
import pyarrow.parquet as pq
from distributed import Client

from toolkit.align import scan as sc
from toolkit.app.fleet import (
    Outcome,
    _attempt,
    _each,
    _may_replace,
    is_toolkit_run,
    parse_scheduler,
)
from toolkit.dataset import (
    META,
    ROW_GROUP_SCANS,
    SCANS,
    LaserGeometry,
    read_scan_rows,
    sha256,
)
from toolkit.errors import ToolkitError
from toolkit.mapping import Settings, has_odometry, map_run, recorded_settings

if TYPE_CHECKING:
    from toolkit.slam.pipeline import SlamConfig

CHUNK_PAIRS = ROW_GROUP_SCANS  # pairs per task: ~0.1 s of work, 3 MB of scans to ship or read


def pair_chunks(ref: np.ndarray, chunk: int = CHUNK_PAIRS) -> list[tuple[int, int, int]]:
    """(first, lo, hi) per chunk of pairs lo..hi-1 (pair k matches scan k+1 to ref[k+1]).

    Chunk k holds the pairs whose current scans are k*chunk .. (k+1)*chunk - 1: exactly one
    row group of a scans.parquet written in row groups of `chunk` scans. `first` is the
    earliest scan the chunk needs, its first pair's reference (the overlap)."""
    n = len(ref) - 1
    if n < 1:
        return []
    bounds = sorted({0, n, *range(chunk - 1, n, chunk)})
    return [(int(ref[lo + 1]), lo, hi) for lo, hi in itertools.pairwise(bounds)]


def chunk_plan(
    refs: np.ndarray, seeds: np.ndarray, lo: int, hi: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The pairs lo..hi-1 as a small log of their own: (earlier, ref, seeds, skip).

    The small log's scans are `earlier` (the scans before lo+1 that these pairs use as
    references: the keyframe overlap, one scan with keyframes or consecutive pairs) followed
    by scans lo+1..hi; `ref` and `seeds` are for `match_pairs` on it. With several earlier
    references, the first `skip` pairs match them to each other and are dropped."""
    cur = refs[lo + 1 : hi + 1]
    earlier = np.unique(cur[cur <= lo])
    m = len(earlier)
    local_ref = np.empty(m + hi - lo, dtype=np.int64)
    local_ref[:m] = np.maximum(np.arange(m) - 1, 0)
    local_ref[m:] = np.where(cur <= lo, np.searchsorted(earlier, cur), cur - (lo + 1) + m)
    local_seeds = np.vstack([np.zeros((m - 1, 3)), seeds[lo:hi]])
    return earlier, local_ref, local_seeds, m - 1


def _match_chunk(
    earlier: np.ndarray,
    own: np.ndarray | tuple[str, int, int],
    seeds: np.ndarray,
    laser: LaserGeometry,
    config: sc.MatchConfig,
    ref: np.ndarray,
    skip: int,
    threads: int | None,
) -> tuple[sc.PairMatches, float]:
    """Worker side: match a chunk's pairs (see `chunk_plan`); `own` is the chunk's scans, or
    (scans.parquet, start, stop) to read them from the dataset on shared storage. Returns
    the pairs after `skip` and the seconds spent in the task (reading and matching)."""
    t0 = time.perf_counter()
    if threads:
        _cap_threads(threads)
    if isinstance(own, tuple):
        path, start, stop = own
        own = read_scan_rows(Path(path), start, stop)
    out = sc.match_pairs(np.vstack([earlier, own]), seeds, laser, config, ref)
    return out.take(slice(skip, None)), time.perf_counter() - t0


def _cap_threads(threads: int) -> None:
    """At most `threads` numba threads in this process (a worker's share of its cores)."""
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]


@dataclass
class ChunkTimes:
    """Where a cluster run's time went: the whole call, and the tasks' own time."""

    wall: float = 0.0  # submit to gathered, seconds
    inside: list[float] = field(default_factory=list)  # per task: reading + matching
    pairs: list[int] = field(default_factory=list)  # per task


def row_group_scans(scans: Path) -> int:
    """The scans per row group of a scans.parquet (its first group's), the natural chunk."""
    meta = pq.ParquetFile(scans).metadata
    return max(meta.row_group(0).num_rows, 2) if meta.num_row_groups else CHUNK_PAIRS


def match_pairs_on(
    client: Client | None,
    ranges: np.ndarray,
    seeds: np.ndarray,
    laser: LaserGeometry,
    config: sc.MatchConfig | None = None,
    ref: np.ndarray | None = None,
    chunk: int | None = None,
    threads: int | None = 1,
    scans: Path | None = None,
    times: ChunkTimes | None = None,
) -> sc.PairMatches:
    """`match_pairs` with the pairs cut into chunks run as Dask tasks on `client` (None: in
    this process, all at once). Same arguments, same result, bit for bit.

    With `scans` (the dataset's scans.parquet, whose rows are `ranges`, on storage the
    workers share), each worker reads its own chunk's rows and the client ships only seeds,
    indices and the chunk's earlier reference scans; the chunk defaults to the file's row
    group, so a worker decodes exactly one. Without, the client scatters each chunk's scans.
    Reference scans must not go backwards (`keyframes` and consecutive pairs don't).
    `threads` caps numba's threads per task (one per worker process by default; None leaves
    numba's default). `times`, if given, is filled with the wall and in-task seconds."""
    config = config or sc.MatchConfig()
    if client is None:
        return sc.match_pairs(ranges, seeds, laser, config, ref)
    refs = sc.pair_refs(ref, len(ranges))
    if len(refs) > 2 and (np.diff(refs[1:]) < 0).any():
        raise ValueError("chunked matching needs reference scans that never go backwards")
    if scans is not None:
        scans = Path(scans).resolve()
        if pq.ParquetFile(scans).metadata.num_rows != len(ranges):
            raise ToolkitError(f"has not the {len(ranges)} scans being matched", file=scans)
    chunk = chunk or (row_group_scans(scans) if scans is not None else CHUNK_PAIRS)
    t0 = time.perf_counter()
    bounds = [(lo, hi) for _, lo, hi in pair_chunks(refs, chunk)]
    plans = [chunk_plan(refs, seeds, lo, hi) for lo, hi in bounds]
    if scans is not None:
        owns: list[Any] = [(str(scans), lo + 1, hi + 1) for lo, hi in bounds]
    else:  # straight to the workers, not through the scheduler inside the task graph
        owns = client.scatter([ranges[lo + 1 : hi + 1] for lo, hi in bounds], hash=False)
    futures = [
        client.submit(
            _match_chunk,
            ranges[earlier],
            own,
            local_seeds,
            laser,
            config,
            local_ref,
            skip,
            threads,
            pure=False,
        )
        for (earlier, local_ref, local_seeds, skip), own in zip(plans, owns, strict=True)
    ]
    if not futures:
        return sc.PairMatches.empty(0)
    parts: list[tuple[sc.PairMatches, float]] = client.gather(futures)
    if times is not None:
        times.wall = time.perf_counter() - t0
        times.inside = [seconds for _, seconds in parts]
        times.pairs = [len(m) for m, _ in parts]
    return sc.PairMatches.concat([m for m, _ in parts])


def matcher_for(
    client: Client | None, chunk: int | None = None, scans: Path | None = None
) -> Callable[..., sc.PairMatches]:
    """A `match_pairs`-shaped callable that runs on `client` (for `poses.build`); with
    `scans`, the workers read the chunks' scans from that file (see `match_pairs_on`)."""

    def match(
        ranges: np.ndarray,
        seeds: np.ndarray,
        laser: LaserGeometry,
        config: sc.MatchConfig | None = None,
        ref: np.ndarray | None = None,
    ) -> sc.PairMatches:
        return match_pairs_on(client, ranges, seeds, laser, config, ref, chunk, scans=scans)

    return match


def run_is_current(
    run: Path,
    dataset: Path,
    method: str,
    voxel: float,
    loops: bool = True,
    config: sc.MatchConfig | None = None,
    slam_config: SlamConfig | None = None,
) -> bool:
    """True when `run` is a finished run (metrics.json is written last; the run directory is
    renamed into place whole) of the same inputs and settings: the dataset's meta.json
    (written last by an import: its sources' sha256 and creation time), the method, the voxel
    size, and the matcher's and the mapper's settings as config.json records them
    (`recorded_settings`: `config` and `slam_config`, None for the defaults; the mapper's
    null without loops). A run of other settings (a --set, an older default) is not."""
    try:
        recorded = json.loads((run / "config.json").read_text())
        if not (run / "metrics.json").is_file():
            return False
        expected = recorded_settings(method, loops, config, slam_config, has_odometry(dataset))
        return bool(
            recorded.get("dataset_meta_sha256") == sha256(dataset / META)
            and recorded.get("method") == method
            and recorded.get("voxel") == voxel
            and recorded.get("matcher") == expected["matcher"]
            and recorded.get("slam") == expected["slam"]
        )
    except (OSError, ValueError):
        return False


def _map_one(
    dataset: Path,
    run: Path,
    method: str,
    voxel: float,
    force: bool,
    threads: int | None,
    matcher: Callable[..., sc.PairMatches] | None = None,
    loops: bool = True,
    config: sc.MatchConfig | None = None,
    slam_config: SlamConfig | None = None,
) -> Outcome:
    """One dataset into one run directory (on a worker: `threads` numba threads), by
    `config` and `slam_config` (None: the defaults)."""

    def work() -> str:
        if not force and run_is_current(run, dataset, method, voxel, loops, config, slam_config):
            return "skipped"
        if threads:
            _cap_threads(threads)
        replace = _may_replace(run, force, is_toolkit_run)
        map_run(
            dataset,
            run,
            method,
            voxel,
            config,
            force=replace,
            matcher=matcher,
            loops=loops,
            slam_config=slam_config,
        )
        return "written"

    return _attempt(dataset, run, work)


def map_many(
    client: Client | None,
    datasets: list[tuple[Path, Path]],
    out: Path,
    method: str = "gaussian",
    voxel: float = 0.0,
    force: bool = False,
    shared_storage: bool = False,
    loops: bool = True,
    settings: Mapping[bool, Settings] | None = None,
) -> list[Outcome]:
    """Map every (dataset, name) into out/name, mirroring the names (a fleet's
    dataset=<name> directories stay so). On `client`: one task per dataset (its whole map
    on a worker, one thread); a single gaussian dataset instead has its pairs matched in
    chunks on the cluster and its map drawn here (one long log), its workers reading their
    scans from the dataset when `shared_storage` (else the scans are shipped). Failures
    are returned by dataset and do not stop the others; current runs (of these settings
    too) are skipped unless `force`. `loops`: each map with loop closure and the pose graph
    (`toolkit map`'s default) or the sequential estimate alone. `settings`: the matcher's and
    the mapper's settings (frozen dataclasses, pickled to the workers as they are; None: the
    defaults) for a dataset with odometry (True) and one without (False), whose front ends
    run different matchers (`toolkit.mapping.matcher_of`); None: the defaults for all."""
    jobs = [(dataset.resolve(), out / name) for dataset, name in datasets]

    def settings_of(dataset: Path) -> tuple[bool, sc.MatchConfig | None, SlamConfig | None]:
        if settings is None:
            return (loops, None, None)
        return (loops, *settings[has_odometry(dataset)])

    if client is not None and len(jobs) == 1 and method == "gaussian":
        dataset, run = jobs[0]
        matcher = matcher_for(client, scans=dataset / SCANS if shared_storage else None)
        return [_map_one(dataset, run, method, voxel, force, None, matcher, *settings_of(dataset))]
    threads = 1 if client is not None else None
    return _each(
        client,
        "map datasets",
        _map_one,
        [(*job, method, voxel, force, threads, None, *settings_of(job[0])) for job in jobs],
    )


def on_shared_storage(scheduler: str | None) -> bool:
    """Whether the workers of `scheduler` read a dataset's scans themselves: yes on a
    scheduler given by address (the cluster shares the paths; shipping the scans from this
    process would make its network the limit), no on a LocalCluster (same machine: shipping
    the scans in memory costs about what decoding them again does, see bench_scale)."""
    return parse_scheduler(scheduler)[0] not in ("none", "local")
