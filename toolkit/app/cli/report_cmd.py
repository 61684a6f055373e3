"""`toolkit report [DATASET...] --out REPORT`"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Annotated

import typer

from toolkit.app.cli import app
from toolkit.errors import ToolkitError


@app.command("report", short_help="Write the paper's figures and tables, measured now.")
def report_command(
    out: Annotated[Path, typer.Option("--out", metavar="DIR", help="report folder to write")],
    datasets: Annotated[
        list[Path] | None,
        typer.Argument(
            metavar="DATASET",
            show_default=False,
            help="dataset directories to map, label and score "
            "(default: the bundled logs of datasets/catalog.json)",
        ),
    ] = None,
    regions: Annotated[
        Path | None,
        typer.Option(
            metavar="CSV",
            help="training regions CSV (feature,start,end) for the datasets given; "
            "default: regions.csv in each dataset folder",
        ),
    ] = None,
    real: Annotated[
        Path | None,
        typer.Option(
            metavar="DIR",
            help="folder of real logs (default: $TOOLKIT_REAL_DATA or ../shared/data/real)",
        ),
    ] = None,
    no_real: Annotated[bool, typer.Option("--no-real", help="leave the real logs out")] = False,
    quick: Annotated[
        bool, typer.Option("--quick", help="fewer trials and cloud sizes (tests, CI)")
    ] = False,
    seed: Annotated[
        int,
        typer.Option(
            metavar="N", help="seed of the simulator (the corridor, the drift added to Intel)"
        ),
    ] = 0,
    force: Annotated[bool, typer.Option("--force", help="replace an existing report")] = False,
) -> None:
    """Write the paper's figures and tables, measured now: index.html, PNG/SVG, CSV/MD/LaTeX.

    Simulates the corridor, imports the real logs it uses, maps every log with each method and labels the logs that have training regions; what a missing piece prevents is marked "not available" in the report.
    """
    import reports  # on use: the report loads matplotlib and every part of the toolkit
    from reports.base import Section
    from toolkit.progress import enabled

    def line(s: Section) -> str:
        extra = "; ".join(s.unavailable) if s.unavailable else ""
        return f"{s.status:13s} {s.title} ({s.seconds:.0f} s)" + (f"  ({extra})" if extra else "")

    def done(s: Section) -> None:  # not on a terminal: a line per section as it finishes
        typer.echo(line(s))
        sys.stdout.flush()

    live = not enabled()  # on a terminal the bar counts the sections, the lines come after
    report = reports.build(
        out,
        datasets or [],
        regions=regions,
        quick=quick,
        seed=seed,
        real=False if no_real else (real or True),
        force=force,
        command=shlex.join(["toolkit", *sys.argv[1:]]),
        on_section=done if live else None,
    )
    if not live:
        for s in report.sections:
            typer.echo(line(s))
    typer.echo(f"report in {report.path}/index.html ({report.seconds:.1f} s)")
    if report.failed:
        names = ", ".join(s.key for s in report.failed)
        raise ToolkitError(f"sections failed: {names} (the report says why)", file=report.path)
