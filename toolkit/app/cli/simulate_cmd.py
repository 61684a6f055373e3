"""`toolkit simulate SCENARIO --out DIR --format F [--seed N] [--scans N] [--config FILE.json]`"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from toolkit.app.cli import app
from toolkit.app.cli.options import key_values
from toolkit.atomic import check_output
from toolkit.errors import ToolkitError


def _pairs(pairs: list[str] | None, flag: str) -> dict[str, Any]:
    """KEY=VALUE text; the simulator and the writer convert each to its field's type."""
    return {k.replace("-", "_"): v for k, v in key_values(pairs, flag).items()}


def _config(path: Path | None) -> dict[str, Any]:
    if path is None:
        return {}
    from toolkit.app.settings import read_json  # here: settings imports this package

    data = read_json(path)
    params = data.get("params", data)  # a simulation.json works as a config too
    if not isinstance(params, dict):
        raise ToolkitError("'params' must be an object", file=path)
    params = {k: v for k, v in params.items() if k not in ("rate_hz", "head")}  # derived
    if "seed" in data:
        params.setdefault("seed", data["seed"])
    return params


@app.command("simulate", short_help="Simulate a log with known truth, in a native format.")
def simulate_command(
    scenario: Annotated[
        str,
        typer.Argument(
            metavar="SCENARIO",
            help="corridor (the paper's Fig. 1), building (-p laps=N: N times round its ring, "
            "for loop closure), or random (a new world per --seed; -p route=1: the other way "
            "through it; -p entered=true: into rooms and turning there; with it -p brief=true: "
            "short visits to small rooms as well; -p revisit=true: back to the start along the "
            "same corridors)",
        ),
    ],
    out: Annotated[Path, typer.Option("--out", metavar="DIR", help="directory to write")],
    fmt: Annotated[
        str,
        typer.Option(
            "--format",
            "-f",
            metavar="FORMAT",
            help="a format with a writer (see `toolkit formats`), or dataset",
        ),
    ],
    seed: Annotated[int | None, typer.Option(metavar="N", help="random seed (default 0)")] = None,
    scans: Annotated[
        int | None, typer.Option(metavar="N", help="number of scans (default per scenario)")
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(metavar="JSON", help="JSON object of parameters (or a simulation.json)"),
    ] = None,
    speed: Annotated[float | None, typer.Option(metavar="M/S", help="robot speed, m/s")] = None,
    units: Annotated[
        str | None,
        typer.Option(metavar="cm|mm", help="LMS-200 units: cm (80 m, 1 cm) or mm (8 m, 1 mm)"),
    ] = None,
    range_sigma: Annotated[
        float | None, typer.Option(metavar="M", help="laser range noise, m")
    ] = None,
    glass_normal_deg: Annotated[
        float | None,
        typer.Option(metavar="DEG", help="glass returns within this angle of normal, deg"),
    ] = None,
    mixed_prob: Annotated[
        float | None, typer.Option(metavar="P", help="chance of a mixed pixel at a depth edge")
    ] = None,
    wheel_diff: Annotated[
        float | None,
        typer.Option(metavar="R", help="relative wheel diameter difference (heading drift)"),
    ] = None,
    scale_error: Annotated[
        float | None, typer.Option(metavar="R", help="odometry scale error")
    ] = None,
    wheel_noise: Annotated[
        float | None, typer.Option(metavar="M", help="wheel noise, m per sqrt(m)")
    ] = None,
    slip_prob: Annotated[
        float | None, typer.Option(metavar="P", help="wheel slip chance per scan")
    ] = None,
    param: Annotated[
        list[str] | None,
        typer.Option(
            "--param",
            "-p",
            metavar="KEY=VALUE",
            help="any model parameter, repeatable: scans, speed, turn_rate, t0, sway, "
            "sway_period (a hand-held scanner's swing) or a field of LaserModel or "
            "OdometryModel (toolkit/sim)",
        ),
    ] = None,
    option: Annotated[
        list[str] | None,
        typer.Option(
            "--option",
            "-O",
            metavar="KEY=VALUE",
            help="a writer option, repeatable (`toolkit formats`; e.g. lms200 baud=38400)",
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="replace an existing DIR")] = False,
) -> None:
    """Simulate a scenario with known truth and write it in a native format, atomically.

    DIR gets the format's files, truth.parquet (t, x, y, theta, label, section), regions.csv
    (feature,start,end) and simulation.json (scenario, seed, every model parameter).
    """
    # on use: the simulator, pandas and the format writers load for `simulate` alone
    from toolkit.app.simulation import write_simulation
    from toolkit.sim import simulate

    check_output(out, force)
    params = _config(config)
    params.update(_pairs(param, "--param"))
    named = {
        "seed": seed,
        "scans": scans,
        "speed": speed,
        "units": units,
        "range_sigma": range_sigma,
        "glass_normal_deg": glass_normal_deg,
        "mixed_prob": mixed_prob,
        "wheel_diff": wheel_diff,
        "scale_error": scale_error,
        "wheel_noise": wheel_noise,
        "slip_prob": slip_prob,
    }
    params.update({k: v for k, v in named.items() if v is not None})
    run_seed = int(params.pop("seed", 0))
    sim = simulate(scenario, seed=run_seed, **params)
    files = write_simulation(sim, out, fmt, force=force, **_pairs(option, "--option"))
    labels = ", ".join(sorted(set(sim.regions.feature)))
    typer.echo(
        f"{scenario} (seed {run_seed}): {sim.dataset.n_scans} scans x {sim.dataset.n_beams} "
        f"beams at {sim.params['rate_hz']:.2f} Hz, {fmt} -> {out}"
    )
    typer.echo(f"features   {labels}")
    for path in files:
        typer.echo(f"  {path}")
