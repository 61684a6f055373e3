"""`toolkit info DATASET [--json]`"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from toolkit.app.cli import app


def print_summary(s: dict[str, Any]) -> None:
    def opt(v: object, unit: str = "") -> str:
        return "-" if v is None else f"{v}{unit}"

    lines = [
        f"dataset    {s['path']}  ({s['format']})",
        f"scans      {s['scans']} x {s['beams']} beams, fov {s['fov_deg']}° from "
        f"{s['angle_min_deg']}° step {s['angle_increment_deg']}°, range_max {s['range_max']} m, "
        f"{100 * s['returns_fraction']:.1f}% returns",
        f"time       {s['duration_s']} s at {opt(s['rate_hz'], ' Hz')} (clock: {s['time_source']})",
        f"odometry   {opt(s['odometry'], ' poses')}, path {opt(s['odometry_path_m'], ' m')}",
        f"truth      {opt(s['groundtruth'], ' poses')}, path {opt(s['groundtruth_path_m'], ' m')}",
    ]
    for name, n in s["lasers"].items():
        lines.append(f"laser      {name}: {n} scans")
    for name, n in s["poses"].items():
        lines.append(f"poses      {name}: {n}")
    lines.append(f"records    {opt(s['records_read'])} read, {s['records_dropped']} dropped")
    for reason, n in s["dropped"].items():
        lines.append(f"  dropped  {n} x {reason}")
    for note in s["notes"]:
        lines.append(f"  note     {note}")
    typer.echo("\n".join(lines))


@app.command("info", short_help="Summarise a dataset.")
def info_command(
    dataset: Annotated[Path, typer.Argument(metavar="DATASET", help="dataset directory")],
    as_json: Annotated[bool, typer.Option("--json", help="print JSON")] = False,
) -> None:
    """Summarise a dataset: scans, beams, field of view, duration and rate, poses, drops."""
    from toolkit.info import summary_of  # numpy and pyarrow: a command module loads on use

    s = summary_of(dataset)
    if as_json:
        typer.echo(json.dumps(s, indent=2))
    else:
        print_summary(s)
