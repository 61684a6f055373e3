"""Maps of logs whose laser sees the robot itself, and the beams `toolkit map` leaves out.

    python -m bench.robot_in_view --worlds 418-425             # the simulator, KISS-ICP beside
    python -m bench.robot_in_view --worlds 418-421 --no-kiss
    python -m bench.robot_in_view --real                        # the real logs: beams found
    python -m bench.robot_in_view --worlds 458-465 --no-odometry  # as LMS-200 captures
    python -m bench.robot_in_view --real --no-odometry

The simulator's corridor and building (600 scans, world = seed) with the first and last
`--edge` beams reading the robot's frame at 0.3 m (5 mm of noise): the odometry's ATE, the
clean log's by `toolkit map` (`toolkit.mapping.map_run`), the mapper given every beam
(`toolkit.slam.run.slam_trajectory`, as before the beams were left out), `toolkit map` (the
fixed beams left out), the beams it found, and with `--kiss` KISS-ICP seeded by the same
odometry (best of voxel 0.1 / 0.3 m) on the clean and the seen log; `narrow`: the clean log
with the same beams left out (what the narrower view costs). `--no-odometry`: the logs
without odometry, as raw LMS-200 captures (2,000 scans unless `--scans`: the mapper needs
them dense without odometry; KISS-ICP with its constant velocity). `--real`: the beams
`toolkit.beams.fixed_beams` finds on the real CARMEN logs' drifted odometry over `--seeds`,
both directions; with `--no-odometry` on every real log read without its odometry (none
expected either way). docs/maps.md, "Beams that see the robot".
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import importers
from bench.bench_slam import (
    REAL,
    ate,
    drifted_both_ways,
    kiss_best,
    map_metrics,
    print_row,
    real_logs,
    sim_worlds,
)
from importers.base import ImportOptions
from toolkit.beams import fixed_beams, without_beams
from toolkit.dataset import Dataset
from toolkit.slam.run import slam_trajectory
from toolkit.typed import int_ranges


def seeing_the_robot(ds: Dataset, edge: int, seed: int) -> Dataset:
    """`ds` with its first and last `edge` beams reading the robot's frame at 0.3 m."""
    ranges = ds.ranges.copy()
    rng = np.random.default_rng(seed)
    for beams in (slice(0, edge), slice(-edge, None)):
        ranges[:, beams] = 0.3 + rng.normal(0, 0.005, ranges[:, beams].shape)
    return replace(ds, ranges=ranges)


def mapped(ds: Dataset) -> dict[str, Any]:
    """`toolkit map`'s ATE and the beams it left out."""
    metrics = map_metrics(ds)
    return {"ate": metrics["ate"]["rmse"], "left_out": len(metrics.get("fixed_beams", []))}


def simulated(
    worlds: tuple[int, ...], edges: tuple[int, ...], kiss: bool, scans: int, with_odometry: bool
) -> pd.DataFrame:
    rows = []
    for world, seed, log, truth, odometry in sim_worlds(worlds, scans=scans):
        ds = log if with_odometry else replace(log, odometry=None)
        clean = mapped(ds)
        base: dict[str, Any] = {"world": world, "seed": seed}
        if with_odometry:
            base["odometry"] = ate(odometry, truth)
        base |= {"clean": clean["ate"], "clean_left_out": clean["left_out"]}
        if kiss:
            base["kiss_clean"] = ate(kiss_best(ds)[0], truth)
        for edge in edges:
            seen = seeing_the_robot(ds, edge, seed)
            every, _ = slam_trajectory(seen)
            run = mapped(seen)
            beams = np.r_[0:edge, ds.n_beams - edge : ds.n_beams]
            row = base | {"edge": edge, "every_beam": ate(every.poses, truth)}
            row |= {"toolkit_map": run["ate"], "left_out": run["left_out"]}
            row["narrow"] = mapped(without_beams(ds, beams))["ate"]
            if kiss:
                row["kiss"] = ate(kiss_best(seen)[0], truth)
            rows.append(row)
            print_row(row)
    return pd.DataFrame(rows)


def real(seeds: tuple[int, ...]) -> pd.DataFrame:
    rows = []
    for name, seed, direction, drifted, odometry in drifted_both_ways(seeds):
        found = fixed_beams(drifted.ranges, odometry)
        rows.append({"log": name, "seed": seed, "drift": direction, "found": len(found)})
    return pd.DataFrame(rows)


#: the real logs that are not corrected CARMEN logs, and their import options
OTHER_REAL = {
    "csm_laserazos/laserazosSM3.log": {},
    "dpslam_loop5/loop5.log": {},
    "breezyslam_mines_urg04lx/exp1.dat": {"preset": "mines"},
    "breezyslam_mines_urg04lx/exp2.dat": {"preset": "mines"},
    "ccny_scan_tools_bags/laser_scan_matcher/demo.bag": {},
    "ccny_scan_tools_bags/laser_scan_sparsifier/demo.bag": {},
}


def real_without_odometry() -> pd.DataFrame:
    """The beams found on every real log read as if it had no odometry."""
    rows = []
    for name, ds in real_logs():
        rows.append({"log": name, "found": len(fixed_beams(ds.ranges, None))})
    for source, options in OTHER_REAL.items():
        importer, paths = importers.resolve("table" if options else "auto", [REAL / source])
        ds = importer.read(paths, importers.read_options(importer, ImportOptions(extra=options)))
        rows.append({"log": source, "found": len(fixed_beams(ds.ranges, None))})
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", type=int_ranges, default="418-425")
    parser.add_argument("--edge", type=int_ranges, default="20,40", help="beams at each edge")
    parser.add_argument("--no-kiss", dest="kiss", action="store_false", help="no KISS-ICP")
    parser.add_argument("--real", action="store_true", help="the real logs' beams instead")
    parser.add_argument("--seeds", type=int_ranges, default="575-584", help="with --real")
    parser.add_argument(
        "--no-odometry", dest="odometry", action="store_false", help="the logs without odometry"
    )
    parser.add_argument(
        "--scans", type=int, help="scans per simulated log (600; 2,000 without odometry)"
    )
    parser.add_argument("--out", type=Path, default=Path("out/robot_in_view.csv"))
    args = parser.parse_args()
    if args.real:
        table = real(args.seeds) if args.odometry else real_without_odometry()
    else:
        scans = args.scans or (600 if args.odometry else 2000)
        table = simulated(args.worlds, args.edge, args.kiss, scans, args.odometry)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out, index=False)
    if args.real:
        print(table.groupby("log")["found"].sum().to_string())
        print(f"{len(table)} runs, {int((table['found'] > 0).sum())} with a beam found")
        return
    numbers = [
        c
        for c in ("odometry", "clean", "every_beam", "toolkit_map", "narrow", "kiss_clean", "kiss")
        if c in table
    ]
    print(table.groupby(["world", "edge"])[numbers].median().round(3).to_string())
    print(
        f"beams found where none were fixed: {int(table['clean_left_out'].sum())}; "
        f"runs that found other than 2 x edge: {int((table['left_out'] != 2 * table['edge']).sum())}"
    )


if __name__ == "__main__":
    main()
