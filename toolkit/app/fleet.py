"""Fleets on Dask: many logs imported (`import_many`) one task each, and a fleet's layout:
hive-partitioned directories FLEET/dataset=<name> (`partition_dir`), found by
`find_logs` / `find_datasets`; the cluster itself (`client_for`). The matching side (a long
log's pairs in chunks on the cluster, `map_many`) is `toolkit.app.fleet_map`, so that
importing a fleet loads neither the matcher nor the mapper.

Schedulers: None or "none" (this process), "local" / "local:N" (a LocalCluster of N worker
processes, one thread each), or the address of a running `dask scheduler` (tcp://host:8786).
"""

from __future__ import annotations

import glob
import json
import os
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote

from distributed import Client, LocalCluster, as_completed

import importers
from importers.base import ImportOptions, strip_compression_suffix
from toolkit.dataset import (
    META,
    is_dataset_dir,
    sha256,
)
from toolkit.errors import ToolkitError
from toolkit.progress import track

CONNECT_TIMEOUT = "10s"  # to reach a scheduler given by address
WORKER_PRELOAD = "toolkit.app.fleet_worker"  # run in every LocalCluster worker as it starts


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
    processes with one thread each ("local", "local:N"), or to the scheduler at an address.
    A LocalCluster's workers are killed by the kernel when this process dies, even by
    SIGKILL (`toolkit.app.fleet_worker`): none outlives it, none prints on its stderr."""
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
                preload=[WORKER_PRELOAD],  # each worker dies with this process
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
