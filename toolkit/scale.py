"""Scale out on Dask: the same matching on a cluster of worker processes, bit for bit.

    with client_for("local:4") as client:             # None in-process, or a Dask Client
        matches = match_pairs_on(client, ranges, seeds, laser, config, ref)

The pair list (reference keyframe and seed of every scan, from odometry) is known before any
matching, so a long log is cut into chunks of consecutive pairs. A chunk [lo, hi) ships the
scans from the keyframe of its first pair (the overlap: one scan for consecutive pairs, back
to the current keyframe with keyframes) to its last scan; the worker matches them with
`toolkit.align.scan.match_pairs` and the chunks' relative poses are gathered in order. Every
pair is matched by the same kernel from the same inputs wherever it runs, so the composed
trajectory equals the single-process run exactly.

Schedulers: None or "none" (this process), "local" / "local:N" (a LocalCluster of N worker
processes, one thread each), or the address of a running `dask scheduler` (tcp://host:8786).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from toolkit.align import scan as sc
from toolkit.dataset import LaserGeometry
from toolkit.errors import ToolkitError

if TYPE_CHECKING:
    from distributed import Client

CHUNK_PAIRS = 2_000  # pairs per task: seconds of work, a few MB of scans to ship
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
    return scheduler, workers or 0


@contextmanager
def client_for(scheduler: str | None, workers: int | None = None) -> Iterator[Client | None]:
    """None for in-process work, else a Dask Client: to a fresh LocalCluster of `workers`
    processes with one thread each ("local", "local:N"), or to the scheduler at an address."""
    kind, n = parse_scheduler(scheduler, workers)
    if kind == "none":
        yield None
        return
    from distributed import Client, LocalCluster

    if kind == "local":
        with (
            LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",
                host="127.0.0.1",
            ) as cluster,
            Client(cluster) as client,
        ):
            yield client
        return
    try:
        client = Client(kind, timeout=CONNECT_TIMEOUT)
    except OSError as e:
        raise ToolkitError(f"cannot reach the Dask scheduler at {kind}: {e}") from None
    with client:
        yield client


def pair_chunks(ref: np.ndarray, chunk: int = CHUNK_PAIRS) -> list[tuple[int, int, int]]:
    """(first, lo, hi) per chunk of pairs lo..hi-1 (pair k matches scan k+1 to ref[k+1]):
    `first` is the earliest scan the chunk needs, its first pair's reference."""
    n = len(ref) - 1
    return [(int(ref[lo + 1]), lo, min(lo + chunk, n)) for lo in range(0, n, chunk)]


def _match_chunk(
    ranges: np.ndarray,
    seeds: np.ndarray,
    laser: LaserGeometry,
    config: sc.MatchConfig,
    ref: np.ndarray,
    skip: int,
    threads: int | None,
) -> sc.PairMatches:
    """Worker side: match scans 1.. of the slice `ranges` against `ref` (slice indices), keep
    the pairs after the first `skip` (those before the chunk, matched only as overlap)."""
    if threads:
        import numba

        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    out = sc.match_pairs(ranges, seeds, laser, config, ref)
    return _take(out, slice(skip, None))


def _take(m: sc.PairMatches, part: slice) -> sc.PairMatches:
    return sc.PairMatches(
        m.pose[part],
        m.covariance[part],
        m.sigma[part],
        m.used[part],
        m.degenerate[part],
        m.agreement[part],
    )


def concat(parts: list[sc.PairMatches]) -> sc.PairMatches:
    """The chunks' matches, in order, as one PairMatches."""
    fields = ("pose", "covariance", "sigma", "used", "degenerate", "agreement")
    return sc.PairMatches(*(np.concatenate([getattr(p, f) for p in parts]) for f in fields))


def match_pairs_on(
    client: Client | None,
    ranges: np.ndarray,
    seeds: np.ndarray,
    laser: LaserGeometry,
    config: sc.MatchConfig | None = None,
    ref: np.ndarray | None = None,
    chunk: int = CHUNK_PAIRS,
    threads: int | None = 1,
) -> sc.PairMatches:
    """`match_pairs` with the pairs cut into chunks run as Dask tasks on `client` (None: in
    this process, all at once). Same arguments, same result, bit for bit.

    Reference scans must not go backwards (`keyframes` and consecutive pairs don't), so a
    chunk's scans are one contiguous slice. `threads` caps numba's threads per task (one per
    worker process by default; None leaves numba's default)."""
    config = config or sc.MatchConfig()
    if client is None:
        return sc.match_pairs(ranges, seeds, laser, config, ref)
    refs = sc._refs(ref, len(ranges))
    if len(refs) > 2 and (np.diff(refs[1:]) < 0).any():
        raise ValueError("chunked matching needs reference scans that never go backwards")
    futures = []
    chunks = pair_chunks(refs, chunk)
    # scans straight to the workers, not through the scheduler inside the task graph
    scans = client.scatter([ranges[first : hi + 1] for first, _, hi in chunks], hash=False)
    for (first, lo, hi), part in zip(chunks, scans, strict=True):
        local_ref = refs[first : hi + 1] - first
        local_ref[0] = 0
        futures.append(
            client.submit(
                _match_chunk,
                part,
                seeds[first:hi],
                laser,
                config,
                local_ref,
                lo - first,
                threads,
                pure=False,
            )
        )
    if not futures:
        return sc.PairMatches.empty(0)
    parts: list[sc.PairMatches] = client.gather(futures)
    return concat(parts)


def matcher_for(client: Client | None, chunk: int = CHUNK_PAIRS) -> Any:
    """A `match_pairs`-shaped callable that runs on `client` (for `trajectory.build`)."""

    def match(
        ranges: np.ndarray,
        seeds: np.ndarray,
        laser: LaserGeometry,
        config: sc.MatchConfig | None = None,
        ref: np.ndarray | None = None,
    ) -> sc.PairMatches:
        return match_pairs_on(client, ranges, seeds, laser, config, ref, chunk)

    return match


# ---------------------------------------------------------------- many logs, one task each

SUFFIXES = (".gz", ".bz2", ".xz")


@dataclass
class Outcome:
    """What happened to one source log: written, skipped (already complete) or failed."""

    source: Path
    dataset: Path
    status: str  # "written" | "skipped" | "failed"
    error: str = ""


def dataset_name(source: Path, root: Path | None) -> Path:
    """The dataset's path under --out: the source's path below `root` (the directory it was
    found in) without its extensions, e.g. robotA/2024-05-01.log.gz -> robotA/2024-05-01."""
    rel = source.relative_to(root) if root is not None else Path(source.name)
    name = rel.name
    while Path(name).suffix.lower() in SUFFIXES:
        name = Path(name).stem
    name = Path(name).stem or name
    return rel.with_name(name)


def find_logs(fmt: str, sources: list[Path]) -> list[tuple[Path, Path]]:
    """(log, dataset name) for every source: files as they are, glob patterns expanded,
    directories walked for what the format's sniffer claims (a directory it claims, such as a
    Rawseeds session, is one log). With 'auto', any format's sniffer."""
    import glob

    import importers

    sniffers = [importers.get(name) for name in (importers.names() if fmt == "auto" else [fmt])]

    def claimed(path: Path) -> bool:
        for imp in sniffers:
            try:
                if imp.sniff(path):
                    return True
            except Exception:  # too damaged to sniff: import it, so the failure is reported
                return True
        return False

    def walk(directory: Path, root: Path) -> list[tuple[Path, Path]]:
        found: list[tuple[Path, Path]] = []
        for child in sorted(directory.iterdir()):
            if child.is_dir():
                found += (
                    [(child, dataset_name(child, root))] if claimed(child) else walk(child, root)
                )
            elif child.is_file() and claimed(child):
                found.append((child, dataset_name(child, root)))
        return found

    logs: list[tuple[Path, Path]] = []
    for source in sources:
        if not source.exists() and glob.has_magic(str(source)):
            matches = sorted(Path(p) for p in glob.glob(str(source), recursive=True))
            if not matches:
                raise ToolkitError("no file matches this pattern", file=source)
            logs += [(p, dataset_name(p, None)) for p in matches if p.is_file() or claimed(p)]
        elif not source.exists():
            raise ToolkitError("no such file or directory", file=source)
        elif source.is_dir() and not claimed(source):
            logs += walk(source, source)
        else:
            logs.append((source, dataset_name(source, None)))
    seen: dict[Path, Path] = {}
    for log, name in logs:
        if name in seen:
            raise ToolkitError(f"{seen[name]} and {log} would both become dataset {name}")
        seen[name] = log
    return logs


def is_complete(dataset: Path, source: Path) -> bool:
    """True when `dataset` holds a finished import (meta.json is written last, atomically) of
    `source` whose files are unchanged (same sha256)."""
    from toolkit.dataset import META, sha256

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


def _import_one(fmt: str, source: Path, out: Path, options: Any, force: bool) -> Outcome:
    """Worker side: one log into one dataset; every failure becomes an Outcome, not a raise."""
    import importers

    try:
        if not force and is_complete(out, source):
            return Outcome(source, out, "skipped")
        importers.import_log(fmt, [source], out, options, force=True)
        return Outcome(source, out, "written")
    except ToolkitError as e:
        return Outcome(source, out, "failed", e.line())
    except Exception as e:  # a damaged log may break a parser anywhere: report it, go on
        return Outcome(source, out, "failed", f"{e} ({type(e).__module__}.{type(e).__name__})")


def import_many(
    client: Client | None,
    fmt: str,
    logs: list[tuple[Path, Path]],
    out: Path,
    options: Any = None,
    force: bool = False,
) -> list[Outcome]:
    """Import every (log, name) into out/name, one task per log on `client` (None: here, one
    after the other). Failures are returned, by source, and do not stop the others; complete
    datasets of unchanged sources are skipped unless `force`."""
    from toolkit.progress import track

    jobs = [(source.resolve(), out / name) for source, name in logs]
    if client is None:
        return [
            _import_one(fmt, source, dataset, options, force)
            for source, dataset in track(jobs, "import logs")
        ]
    from distributed import as_completed

    futures = {
        client.submit(_import_one, fmt, source, dataset, options, force, pure=False): (
            source,
            dataset,
        )
        for source, dataset in jobs
    }
    done: dict[Path, Outcome] = {}
    for future in track(as_completed(futures), "import logs", total=len(futures)):
        source, dataset = futures[future]
        if future.status == "error":  # the worker died (e.g. a crash in native code)
            error = future.exception()
            done[dataset] = Outcome(source, dataset, "failed", f"{error} ({type(error).__name__})")
        else:
            done[dataset] = future.result()
    return [done[dataset] for _, dataset in jobs]
