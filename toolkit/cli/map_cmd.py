"""`toolkit map DATASET --out RUN [--method ...] [--voxel M] [--scheduler none|local:N|ADDRESS]`"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from toolkit.cli import app


@app.command("map")
def map_command(
    dataset: Annotated[Path, typer.Argument(help="dataset directory")],
    out: Annotated[Path, typer.Option("--out", "-o", help="run directory to write")],
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
            help="where to match the scan pairs (gaussian): none (this process), local or local:N "
            "(a Dask LocalCluster of N workers) or a Dask scheduler's address"
        ),
    ] = "none",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no summary")] = False,
) -> None:
    """Align the scans, build the trajectory and the maps, and measure them against ground truth.

    Writes RUN/: config.json, trajectory.parquet, trajectory.tum (evo), cloud.ply, map.png,
    metrics.json; atomically.
    """
    from toolkit.errors import ToolkitError
    from toolkit.mapping import map_dataset
    from toolkit.poses import METHODS
    from toolkit.scale import client_for, matcher_for

    if method not in METHODS:
        raise ToolkitError(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    if voxel < 0:
        raise ToolkitError(f"--voxel must be 0 or positive, not {voxel}")
    if scheduler != "none" and method != "gaussian":
        raise ToolkitError(f"--scheduler runs the gaussian matcher; method {method} runs here only")
    with client_for(scheduler) as client:
        matcher = matcher_for(client) if client is not None else None
        run = map_dataset(dataset, out, method, voxel, force, matcher=matcher)
    if quiet:
        return
    metrics = json.loads((run / "metrics.json").read_text())
    line = f"{run}: {metrics['scans']} scans by {method}"
    if metrics.get("pairs_per_second"):
        line += f", {metrics['pairs_per_second']:.0f} pairs/s"
    if metrics.get("groundtruth"):
        ate, rpe, fails = metrics["ate"], metrics["rpe"], metrics["failures"]
        line += (
            f"; ATE {ate['rmse']:.3f} m, RPE {rpe['translation']:.4f} m "
            f"{rpe['rotation_deg']:.3f}°, {fails['count']} failures"
        )
    typer.echo(line)
