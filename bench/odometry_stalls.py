"""Maps of logs whose odometry stands still while the robot moves, and what `toolkit map` mends.

    python -m bench.odometry_stalls --worlds 434-441            # the simulator, KISS-ICP beside
    python -m bench.odometry_stalls --worlds 426-433 --scans 2000
    python -m bench.odometry_stalls --worlds 0-3 --no-kiss --cases middle,short

The simulator's corridor and building (world = seed; each at its own scan count, 2,000 and
4,000 scans, or `--scans`), their odometry stalled in one of these ways (`--cases`):

- `start`: the odometry stream starts a third of the way in (held at its first pose before);
- `middle`: the encoder stalls over the middle third, then counts on from where it stalled;
- `end`: the odometry stream stops two thirds of the way in (held at its last pose after);
- `short`: the encoder stalls for 30 scans in the middle.

Per run: the stalled odometry's ATE, the mapper given it as logged
(`toolkit.slam.run.slam_trajectory`, as before the stalls were mended), `toolkit map`
(`toolkit.mapping.map_run`: the stalls mended from the scans), the stalls it found, the clean
log's `toolkit map`, the log mapped without any odometry, and with `--kiss` KISS-ICP seeded by
the same stalled odometry (best of voxel 0.1 / 0.3 m). docs/maps.md, "Odometry that stands
still".
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from bench.bench_slam import ate, kiss_best, map_metrics, print_row, sim_worlds
from toolkit import se2
from toolkit.dataset import Dataset, PoseStream
from toolkit.slam.run import slam_trajectory
from toolkit.typed import int_ranges

SHORT = 30  # scans of the `short` stall


def stalled(odometry: np.ndarray, first: int, last: int) -> np.ndarray:
    """`odometry` held at scan `first`'s pose through scan `last`, then going on by its own
    steps from there (an encoder that stops counting and starts again)."""
    out = odometry.copy()
    out[first : last + 1] = odometry[first]
    rest = len(odometry) - last  # from scan `last` on: the held pose, then the odometry's own
    # motion since `last`
    since = se2.between(np.broadcast_to(odometry[last], (rest, 3)), odometry[last:])
    out[last:] = se2.compose(np.broadcast_to(odometry[first], (rest, 3)), since)
    return out


CASES: dict[str, Callable[[int], tuple[int, int]]] = {
    "start": lambda n: (0, n // 3),
    "middle": lambda n: (n // 3, 2 * n // 3),
    "end": lambda n: (2 * n // 3, n - 1),
    "short": lambda n: (n // 2, n // 2 + SHORT),
}


def mapped(ds: Dataset) -> dict[str, Any]:
    """`toolkit map`'s ATE and the stalls it mended."""
    metrics = map_metrics(ds)
    stalls = metrics.get("odometry_stalls", [])
    return {"ate": metrics["ate"]["rmse"], "stalls": [(s["first"], s["last"]) for s in stalls]}


def simulated(
    worlds: tuple[int, ...], cases: list[str], kiss: bool, scans: int | None = None
) -> pd.DataFrame:
    rows = []
    for world, seed, ds, truth, odometry in sim_worlds(worlds, scans):
        clean = mapped(ds)
        blind = replace(ds, odometry=None)
        base = {"world": world, "seed": seed, "scans": ds.n_scans, "clean": clean["ate"]}
        base |= {"clean_found": len(clean["stalls"])}
        base["no_odometry"] = ate(slam_trajectory(blind)[0].poses, truth)
        for case in cases:
            first, last = CASES[case](ds.n_scans)
            wheels = stalled(odometry, first, last)
            log = replace(ds, odometry=PoseStream(ds.t, wheels))
            run = mapped(log)
            row = base | {"case": case, "first": first, "last": last}
            row["odometry"] = ate(wheels, truth)
            row["as_logged"] = ate(slam_trajectory(log)[0].poses, truth)
            row |= {"toolkit_map": run["ate"], "found": str(run["stalls"])}
            if kiss:
                row["kiss"] = ate(kiss_best(log)[0], truth)
            rows.append(row)
            print_row(row)
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", type=int_ranges, default="434-441")
    parser.add_argument("--scans", type=int, default=None, help="per log (default: its own)")
    parser.add_argument("--cases", default=",".join(CASES), help="of " + ", ".join(CASES))
    parser.add_argument("--no-kiss", dest="kiss", action="store_false", help="no KISS-ICP")
    parser.add_argument("--out", type=Path, default=Path("out/odometry_stalls.csv"))
    args = parser.parse_args()
    cases = [c for c in args.cases.split(",") if c]
    unknown = set(cases) - set(CASES)
    if unknown:
        parser.error(f"unknown cases {sorted(unknown)}; known: {', '.join(CASES)}")
    table = simulated(args.worlds, cases, args.kiss, args.scans)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out, index=False)
    numbers = [
        c
        for c in ("odometry", "as_logged", "toolkit_map", "kiss", "clean", "no_odometry")
        if c in table
    ]
    print(table.groupby(["world", "case"], sort=False)[numbers].median().round(3).to_string())
    expected = table.apply(lambda r: str([(r["first"], r["last"])]), axis=1)
    print(
        f"stalls found on the clean logs: {int(table['clean_found'].sum())}; "
        f"runs that found other than the stall: {int((table['found'] != expected).sum())}"
    )


if __name__ == "__main__":
    main()
