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
trajectory equals the single-process run exactly.

Many logs (`import_many`) or many datasets (`map_many`) run one task each; a fleet's datasets
are hive-partitioned directories FLEET/dataset=<name> (`partition_dir`).

Schedulers: None or "none" (this process), "local" / "local:N" (a LocalCluster of N worker
processes, one thread each), or the address of a running `dask scheduler` (tcp://host:8786).
"""

from __future__ import annotations

import glob
import itertools
import json
import os
import re
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numba
import numpy as np
import pyarrow.parquet as pq
from distributed import Client, LocalCluster, as_completed

import importers
from importers.base import ImportOptions, strip_compression_suffix
from toolkit.align import scan as sc
from toolkit.dataset import (
    META,
    ROW_GROUP_SCANS,
    SCANS,
    LaserGeometry,
    is_dataset_dir,
    read_scan_rows,
    sha256,
)
from toolkit.errors import ToolkitError
from toolkit.mapping import map_run
from toolkit.progress import track

CHUNK_PAIRS = ROW_GROUP_SCANS  # pairs per task: ~0.1 s of work, 3 MB of scans to ship or read
CONNECT_TIMEOUT = "10s"  # to reach a scheduler given by address


def parse_scheduler(scheduler: str | None, workers: int | None = None) -> tuple[str, int]:
    """("none" | "local" | address, workers) from a --scheduler value."""
    if scheduler is None or scheduler in ("", "none"):
        return "none", 1
    if scheduler == "local" or scheduler.startswith("local:"):
        _, _, count = scheduler.partition(":")
        try:
            n = int(count) if count else (workers or os.cpu_count() or 1)
        except ValueError:
            raise ToolkitError(
                f"--scheduler {scheduler!r}: N in local:N must be a number"
            ) from None
        if n < 1:
            raise ToolkitError(f"--scheduler {scheduler!r}: needs at least one worker")
        return "local", n
    if not re.fullmatch(r"([a-z]+://)?[A-Za-z0-9_.\-\[\]:]+:\d+/?", scheduler):
        raise ToolkitError(
            f"--scheduler {scheduler!r}: use none, local, local:N or a running Dask "
            "scheduler's address (tcp://HOST:PORT)"
        )
    return scheduler, workers or 0


@contextmanager
def client_for(scheduler: str | None, workers: int | None = None) -> Iterator[Client | None]:
    """None for in-process work, else a Dask Client: to a fresh LocalCluster of `workers`
    processes with one thread each ("local", "local:N"), or to the scheduler at an address."""
    kind, n = parse_scheduler(scheduler, workers)
    if kind == "none":
        yield None
        return
    if kind == "local":
        with (
            LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                dashboard_address="127.0.0.1:0",  # ":0" would serve it on every interface
                host="127.0.0.1",
            ) as cluster,
            Client(cluster) as client,
        ):
            yield client
        return
    try:
        client = Client(kind, timeout=CONNECT_TIMEOUT)
    except (OSError, ValueError, TypeError) as e:
        raise ToolkitError(f"cannot reach the Dask scheduler at {kind}: {e}") from None
    with client:
        yield client


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


# ---------------------------------------------------------------- many logs, one task each

PARTITION = "dataset"  # the fleet's hive partition key: FLEET/dataset=<name>/scans.parquet


@dataclass
class Outcome:
    """What happened to one input (a log, a dataset): written, skipped (complete) or failed."""

    source: Path
    target: Path  # the dataset or run directory
    status: str  # "written" | "skipped" | "failed"
    error: str = ""


def dataset_name(source: Path, root: Path | None) -> Path:
    """The dataset's name: the source's path below `root` (the directory it was found in)
    without its extensions, e.g. robotA/2024-05-01.log.gz -> robotA/2024-05-01."""
    rel = source.relative_to(root) if root is not None else Path(source.name)
    name = strip_compression_suffix(rel.name)
    name = Path(name).stem or name
    return rel.with_name(name)


def partition_dir(name: Path) -> str:
    """A dataset's directory in a fleet: hive style `dataset=<name>`, with '/' and other
    special characters %-escaped as Spark and pyarrow write (and read back) partition values:
    robotA/2024-05-01 -> dataset=robotA%2F2024-05-01."""
    return f"{PARTITION}={quote(name.as_posix(), safe='')}"


def _find(
    sources: list[Path],
    claimed: Callable[[Path], bool],
    taken: Callable[[Path], bool],
    name: Callable[[Path, Path | None], Path],
) -> list[tuple[Path, Path]]:
    """(input, name) for every source: `taken` paths as they are, glob patterns expanded,
    other directories walked for what `claimed` says is one input (not looking inside it)."""

    def walk(directory: Path, root: Path) -> list[tuple[Path, Path]]:
        found: list[tuple[Path, Path]] = []
        for child in sorted(directory.iterdir()):
            if child.name.startswith("."):  # hidden: temporary and lock files of writers
                continue
            if not (child.is_file() or child.is_dir()):  # FIFOs, devices, sockets: not logs
                continue
            if claimed(child):  # sniffed once: every importer's sniffer runs
                found.append((child, name(child, root)))
            elif child.is_dir():
                found += walk(child, root)
        return found

    inputs: list[tuple[Path, Path]] = []
    for source in sources:
        if not source.exists() and glob.has_magic(str(source)):
            matches = sorted(Path(p) for p in glob.glob(str(source), recursive=True))
            if not matches:
                raise ToolkitError("no file matches this pattern", file=source)
            inputs += [(p, name(p, None)) for p in matches if taken(p)]
        elif not source.exists():
            raise ToolkitError("no such file or directory", file=source)
        elif source.is_dir() and not claimed(source):
            inputs += walk(source, source)
        else:
            inputs.append((source, name(source, None)))
    seen: dict[Path, Path] = {}
    for path, key in inputs:
        if key in seen:
            raise ToolkitError(f"{seen[key]} and {path} would both become {key}")
        seen[key] = path
    return inputs


def find_logs(fmt: str, sources: list[Path]) -> list[tuple[Path, Path]]:
    """(log, dataset name) for every source: files as they are, glob patterns expanded,
    directories walked for what the format's sniffer claims (a directory it claims, such as a
    Rawseeds session, is one log). With 'auto', any format's sniffer."""
    sniffers = [importers.get(name) for name in (importers.names() if fmt == "auto" else [fmt])]

    def claimed(path: Path) -> bool:
        if fmt == "auto" and importers.not_a_log(path):
            return False  # the toolkit's own outputs (Parquet, JSON, PLY, TUM) are no logs
        for imp in sniffers:
            try:
                if imp.sniff(path):
                    return True
            except Exception:  # too damaged to sniff: import it, so the failure is reported
                return True
        return False

    return _find(sources, claimed, lambda p: p.is_file() or claimed(p), dataset_name)


def find_datasets(sources: list[Path]) -> list[tuple[Path, Path]]:
    """(dataset directory, name) for every source: dataset directories as they are (named by
    their directory), glob patterns expanded, directory trees (a fleet) walked for datasets,
    named by their path below the tree (a fleet's `dataset=...` directories keep their name)."""

    def name(path: Path, root: Path | None) -> Path:
        return path.relative_to(root) if root is not None else Path(path.name)

    return _find(sources, is_dataset_dir, is_dataset_dir, name)


def is_complete(dataset: Path, source: Path) -> bool:
    """True when `dataset` holds a finished import (meta.json is written last, atomically) of
    `source` whose files are unchanged (same sha256)."""
    meta_path = dataset / META
    if not meta_path.is_file():
        return False
    try:
        files = json.loads(meta_path.read_text())["source"]["files"]
        listed = {Path(f["path"]).resolve(): f["sha256"] for f in files}
    except (ValueError, KeyError, TypeError):
        return False
    if source.is_file() and source.resolve() not in listed:
        return False
    return all(p.is_file() and sha256(p) == digest for p, digest in listed.items())


def is_toolkit_dataset(path: Path) -> bool:
    """A directory holding a finished import's meta.json (of any source): the toolkit's own
    output, which a fleet import may replace without --force when its source changed."""
    try:
        meta = json.loads((path / META).read_text())
        return isinstance(meta, dict) and "format" in meta.get("source", {})
    except (OSError, ValueError, AttributeError):
        return False


def is_toolkit_run(path: Path) -> bool:
    """A directory holding a `toolkit map` run's config.json: the toolkit's own output."""
    try:
        config = json.loads((path / "config.json").read_text())
        return isinstance(config, dict) and "method" in config and "dataset" in config
    except (OSError, ValueError):
        return False


def _may_replace(target: Path, force: bool, ours: Callable[[Path], bool]) -> bool:
    """Whether a fleet task may replace `target`: it is absent, --force was given, or it is
    the toolkit's own output (stale: its source changed). Anything else is the user's."""
    if force or not target.exists() or ours(target):
        return True
    raise ToolkitError(
        "exists and is not the toolkit's output; pass --force to replace it", file=target
    )


def _attempt(source: Path, target: Path, work: Callable[[], str]) -> Outcome:
    """Run `work` (returning "written" or "skipped"); every failure becomes an Outcome."""
    try:
        return Outcome(source, target, work())
    except ToolkitError as e:
        return Outcome(source, target, "failed", e.line())
    except Exception as e:  # a damaged input may break a parser anywhere: report it, go on
        return Outcome(source, target, "failed", f"{e} ({type(e).__module__}.{type(e).__name__})")


def _import_one(
    source: Path, out: Path, fmt: str, options: ImportOptions | None, force: bool
) -> Outcome:
    """Worker side: one log into one dataset."""

    def work() -> str:
        if not force and is_complete(out, source):
            return "skipped"
        replace = _may_replace(out, force, is_toolkit_dataset)
        importers.import_log(fmt, [source], out, options, force=replace)
        return "written"

    return _attempt(source, out, work)


def _each(
    client: Client | None, what: str, fn: Callable[..., Outcome], jobs: list[tuple[Any, ...]]
) -> list[Outcome]:
    """fn(*job) for every job, one task each on `client` (None: here, one after the other);
    each job starts with (source, target). Outcomes in the jobs' order."""
    if client is None:
        return [fn(*job) for job in track(jobs, what)]
    futures = {client.submit(fn, *job, pure=False): job for job in jobs}
    done: dict[Path, Outcome] = {}
    for future in track(as_completed(futures), what, total=len(futures)):
        source, target = futures[future][:2]
        if future.status == "error":  # the worker died (e.g. a crash in native code)
            error = future.exception()
            done[target] = Outcome(source, target, "failed", f"{error} ({type(error).__name__})")
        else:
            done[target] = future.result()
    return [done[job[1]] for job in jobs]


def import_many(
    client: Client | None,
    fmt: str,
    logs: list[tuple[Path, Path]],
    out: Path,
    options: ImportOptions | None = None,
    force: bool = False,
) -> list[Outcome]:
    """Import every (log, name) into the fleet `out`, as out/dataset=<name> (`partition_dir`),
    one task per log on `client` (None: here, one after the other). Failures are returned, by
    source, and do not stop the others; complete datasets of unchanged sources are skipped
    unless `force`."""
    jobs = [
        (source.resolve(), out / partition_dir(name), fmt, options, force) for source, name in logs
    ]
    return _each(client, "import logs", _import_one, jobs)


# ---------------------------------------------------------------- many datasets, one run each


def run_is_current(run: Path, dataset: Path, method: str, voxel: float) -> bool:
    """True when `run` is a finished run (metrics.json is written last; the run directory is
    renamed into place whole) of the same inputs: the dataset's meta.json (written last by an
    import: its sources' sha256 and creation time), the method, the voxel size and, for
    gaussian, the matcher's parameters."""
    try:
        config = json.loads((run / "config.json").read_text())
        if not (run / "metrics.json").is_file():
            return False
        same = (
            config.get("dataset_meta_sha256") == sha256(dataset / META)
            and config.get("method") == method
            and config.get("voxel") == voxel
        )
        matcher = json.loads(json.dumps(sc.MatchConfig().to_dict()))
        return same and (method != "gaussian" or config.get("matcher") == matcher)
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
) -> Outcome:
    """One dataset into one run directory (on a worker: `threads` numba threads)."""

    def work() -> str:
        if not force and run_is_current(run, dataset, method, voxel):
            return "skipped"
        if threads:
            _cap_threads(threads)
        replace = _may_replace(run, force, is_toolkit_run)
        map_run(dataset, run, method, voxel, force=replace, matcher=matcher)
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
) -> list[Outcome]:
    """Map every (dataset, name) into out/name, mirroring the names (a fleet's
    dataset=<name> directories stay so). On `client`: one task per dataset (its whole map
    on a worker, one thread); a single gaussian dataset instead has its pairs matched in
    chunks on the cluster and its map drawn here (one long log), its workers reading their
    scans from the dataset when `shared_storage` (else the scans are shipped). Failures
    are returned by dataset and do not stop the others; current runs are skipped unless
    `force`."""
    jobs = [(dataset.resolve(), out / name) for dataset, name in datasets]
    if client is not None and len(jobs) == 1 and method == "gaussian":
        dataset, run = jobs[0]
        matcher = matcher_for(client, scans=dataset / SCANS if shared_storage else None)
        return [_map_one(dataset, run, method, voxel, force, None, matcher)]
    threads = 1 if client is not None else None
    return _each(
        client, "map datasets", _map_one, [(*job, method, voxel, force, threads) for job in jobs]
    )


def on_shared_storage(scheduler: str | None) -> bool:
    """Whether the workers of `scheduler` read a dataset's scans themselves: yes on a
    scheduler given by address (the cluster shares the paths; shipping the scans from this
    process would make its network the limit), no on a LocalCluster (same machine: shipping
    the scans in memory costs about what decoding them again does, see bench_scale)."""
    return parse_scheduler(scheduler)[0] not in ("none", "local")
