"""`toolkit map DATASET --out RUN [--method ...] [--voxel M] [--scheduler none|local:N|ADDRESS]`,
or `toolkit map DATASET... --out DIR` (several datasets, a fleet's tree, a quoted glob)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from toolkit.app.cli import app


@app.command("map")
def map_command(
    datasets: Annotated[
        list[Path],
        typer.Argument(
            metavar="DATASET",
            help="a dataset directory; or several, a directory tree of them (a fleet), or a "
            "quoted glob: then OUT gets one run per dataset",
        ),
    ],
    out: Annotated[
        Path,
        typer.Option("--out", "-o", help="run directory to write (many datasets: their parent)"),
    ],
    method: Annotated[
        str,
        typer.Option(
            help="gaussian (the paper's scan matcher), icp (2D point-to-line), "
            "icp-point (Open3D point-to-point) or odometry"
        ),
    ] = "gaussian",
    voxel: Annotated[
        float, typer.Option(help="voxel size (m) to downsample cloud.ply; 0 keeps every return")
    ] = 0.0,
    force: Annotated[bool, typer.Option("--force", help="replace an existing run")] = False,
    scheduler: Annotated[
        str,
        typer.Option(
            help="where the work runs: none (this process), local or local:N (a Dask "
            "LocalCluster of N workers) or a Dask scheduler's address; one dataset: its scan "
            "pairs (gaussian), many: one task per dataset"
        ),
    ] = "none",
    each: Annotated[
        bool,
        typer.Option(
            "--each",
            help="many datasets (implied by several DATASETs, a tree or a glob): one run each, "
            "OUT/<name below the tree>; failures by name; current runs are skipped",
        ),
    ] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no summary")] = False,
) -> None:
    """Align the scans, build the trajectory and the maps, and measure them against ground truth.

    Writes RUN/: config.json, trajectory.parquet, trajectory.tum (evo), cloud.ply, map.png,
    metrics.json; atomically. With many datasets, OUT/<name>/ for each.
    """
    from toolkit.app.fleet import client_for, matcher_for, on_shared_storage
    from toolkit.dataset import SCANS
    from toolkit.errors import ToolkitError
    from toolkit.mapping import map_run
    from toolkit.poses import METHODS

    if method not in METHODS:
        raise ToolkitError(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    if voxel < 0:
        raise ToolkitError(f"--voxel must be 0 or positive, not {voxel}")
    if each or _many(datasets):
        _map_each(datasets, out, method, voxel, force, scheduler, quiet)
        return
    dataset = datasets[0]
    if scheduler != "none" and method != "gaussian":
        raise ToolkitError(f"--scheduler runs the gaussian matcher; method {method} runs here only")
    with client_for(scheduler) as client:
        scans = dataset / SCANS if on_shared_storage(scheduler) else None
        matcher = matcher_for(client, scans=scans) if client is not None else None
        run = map_run(dataset, out, method, voxel, force=force, matcher=matcher)
    if quiet:
        return
    metrics = run.metrics
    line = f"{run.path}: {metrics['scans']} scans by {method}"
    if metrics.get("pairs_per_second"):
        line += f", {metrics['pairs_per_second']:.0f} pairs/s"
    if metrics.get("groundtruth"):
        ate, rpe, fails = metrics["ate"], metrics["rpe"], metrics["failures"]
        line += (
            f"; ATE {ate['rmse']:.3f} m, RPE {rpe['translation']:.4f} m "
            f"{rpe['rotation_deg']:.3f}°, {fails['count']} failures"
        )
    typer.echo(line)


def _many(datasets: list[Path]) -> bool:
    """Several inputs, a glob pattern, or a directory that is not itself a dataset."""
    import glob

    from toolkit.dataset import is_dataset_dir

    if len(datasets) != 1:
        return True
    one = datasets[0]
    if not one.exists():
        return glob.has_magic(str(one))
    return one.is_dir() and not is_dataset_dir(one)


def _map_each(
    datasets: list[Path],
    out: Path,
    method: str,
    voxel: float,
    force: bool,
    scheduler: str,
    quiet: bool,
) -> None:
    """One run per dataset; a line per failure on stderr and exit 1 if any failed."""
    from toolkit.app.cli.options import report_outcomes
    from toolkit.app.fleet import client_for, find_datasets, map_many, on_shared_storage
    from toolkit.errors import ToolkitError

    found = find_datasets(datasets)
    if not found:
        raise ToolkitError("no dataset found in the inputs (a dataset directory has meta.json)")
    with client_for(scheduler) as client:
        outcomes = map_many(client, found, out, method, voxel, force, on_shared_storage(scheduler))
    report_outcomes(outcomes, out, "datasets", quiet)
