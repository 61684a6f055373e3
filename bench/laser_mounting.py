"""Maps of logs whose laser is mounted otherwise than the log says, and what `toolkit map` reads.

    python -m bench.laser_mounting --worlds 442-449             # the simulator, KISS-ICP beside
    python -m bench.laser_mounting --real --seeds 0-2           # the real logs: votes only

The simulator's corridor and building (world = seed, each at its own scan count) as logged,
with the beams in the opposite order (a laser mounted upside down, in a format without its
mounting) and with the laser's yaw off by pi (mounted backwards): the mapper given the log
as it says (`toolkit.slam.run.slam_trajectory`), `toolkit map` (`toolkit.mapping.map_run`,
which reads the mounting from the scans and the odometry), what it read, and with `--kiss`
KISS-ICP on the log as it says (best of voxel 0.1 / 0.3 m). `--real`: the votes of
`toolkit.mounting.mounting` on the real CARMEN logs' drifted odometry over `--seeds`, both
directions, as logged, upside down and turned round (the mounting as logged expected, then
the fault). docs/maps.md, "A laser mounted otherwise".
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from bench.bench_slam import ate, drifted_both_ways, kiss_best, map_metrics, print_row, sim_worlds
from toolkit.dataset import Dataset
from toolkit.mounting import mounted, mounting
from toolkit.slam.run import slam_trajectory
from toolkit.typed import int_ranges


def faulted(ds: Dataset, fault: str) -> Dataset:
    """`ds` as a log that says the laser is mounted level and forward while it is not."""
    if fault == "upside down":  # the beams as the turned-over laser lists them
        return replace(ds, ranges=np.ascontiguousarray(ds.ranges[:, ::-1]))
    if fault == "turned round":  # the log says forward; the laser looks back
        return replace(ds, laser=mounted(ds.laser, backwards=True, upside_down=False))
    return ds


FAULTS = ("as logged", "upside down", "turned round")


def mapped(ds: Dataset) -> dict[str, Any]:
    """`toolkit map`'s ATE and the mounting it read."""
    metrics = map_metrics(ds)
    read = metrics.get("laser_mounting", {}).get("read_as", "")
    return {"ate": metrics["ate"]["rmse"], "read_as": read}


def simulated(worlds: tuple[int, ...], kiss: bool) -> pd.DataFrame:
    rows = []
    for world, seed, ds, truth, _ in sim_worlds(worlds):
        for fault in FAULTS:
            log = faulted(ds, fault)
            run = mapped(log)
            row: dict[str, Any] = {"world": world, "seed": seed, "fault": fault}
            row["as_said"] = ate(slam_trajectory(log)[0].poses, truth)
            row |= {"toolkit_map": run["ate"], "read_as": run["read_as"]}
            if kiss:
                row["kiss"] = ate(kiss_best(log)[0], truth)
            rows.append(row)
            print_row(row)
    return pd.DataFrame(rows)


def real(seeds: tuple[int, ...]) -> pd.DataFrame:
    rows = []
    for name, seed, direction, drifted, odometry in drifted_both_ways(seeds):
        for fault in FAULTS:
            log = faulted(drifted, fault)
            votes = mounting(log.ranges, odometry, log.laser)
            row = {"log": name, "seed": seed, "drift": direction, "fault": fault}
            row |= {"read_as": votes.describe()}
            for side, vote in votes.to_dict().items():
                row |= {f"{side}_pairs": vote["pairs"], f"{side}_share": vote["share"]}
            rows.append(row)
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", type=int_ranges, default="442-449")
    parser.add_argument("--no-kiss", dest="kiss", action="store_false", help="no KISS-ICP")
    parser.add_argument("--real", action="store_true", help="the real logs' votes instead")
    parser.add_argument("--seeds", type=int_ranges, default="0-2", help="with --real")
    parser.add_argument("--out", type=Path, default=Path("out/laser_mounting.csv"))
    args = parser.parse_args()
    table = real(args.seeds) if args.real else simulated(args.worlds, args.kiss)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out, index=False)
    read = table["read_as"].fillna("")
    right = np.where(
        table["fault"] == "as logged",
        read == "",
        np.where(
            table["fault"] == "upside down",
            read.str.startswith("upside down"),
            read.str.startswith("turned round") & ~read.str.contains("upside"),
        ),
    )
    if args.real:
        print(table.groupby("fault", sort=False)["read_as"].value_counts().to_string())
        print(f"{len(table)} logs, {int(right.sum())} read as they are mounted")
        return
    numbers = [c for c in ("as_said", "toolkit_map", "kiss") if c in table]
    print(table.groupby(["world", "fault"], sort=False)[numbers].median().round(3).to_string())
    print(f"{len(table)} logs, {int(right.sum())} read as they are mounted")


if __name__ == "__main__":
    main()
