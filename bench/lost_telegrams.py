"""Maps of LMS-200 captures without odometry whose serial line lost telegrams, or whose
host's clock jitters.

    python -m bench.lost_telegrams --worlds 466-473            # the simulator, KISS-ICP beside
    python -m bench.lost_telegrams --worlds 0-3 --no-kiss --errors 0,8e-5
    python -m bench.lost_telegrams --worlds 482-489 --errors 0,8e-5 --jitter 0,0.15
    python -m bench.lost_telegrams --worlds 498-505 --errors 0 --jitter 0,0.15 --formats rosbag

The simulator's corridor (2,000 scans) and building (2,000 and its own 4,000 scans), world =
seed, written as raw LMS-200 captures without odometry whose line flipped a share of its bits
(`--errors`, the writer's `bit_error_rate`; 0: a clean line), and imported as a user would:
the importer skips the damaged telegrams and counts them, and their times (the capture's side
file) leave intervals of two scans or more where they were. `--jitter`: the side file's times
spread around the scans' (the writer's `clock_jitter`, sd in scan periods; the Mines URG logs'
host spreads about 0.15: 5th-95th percentile of their intervals 0.69-1.39 periods).
`--formats rosbag`: the logs written as ROS bags without odometry instead, the scans' header
stamps spread the same way (the bag writer's `clock_jitter`). Per run: the share of the scans
lost, the longest interval (in scans), `toolkit map` (`toolkit.mapping.map_run`) and with
`--kiss` KISS-ICP with its constant velocity (best of voxel 0.1 / 0.3 m; it predicts each
scan's motion as the last one's, whatever the interval). docs/maps.md, "Methods".
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import importers
from bench.bench_slam import ate, kiss_best, map_metrics, map_summary, print_row
from toolkit.app.simulation import write_simulation
from toolkit.dataset import Dataset, load
from toolkit.poses import truth_poses
from toolkit.sim import Simulation, simulate
from toolkit.typed import int_ranges

#: the simulated logs: scenario and scan count (None: its own)
LOGS = (("corridor", 2000), ("building", 2000), ("building", None))


def simulations(worlds: tuple[int, ...]) -> Iterator[Simulation]:
    """Each log of LOGS on each world, without odometry."""
    for scenario, scans in LOGS:
        for seed in worlds:
            sim = simulate(scenario, seed=seed, **({"scans": scans} if scans else {}))
            yield replace(sim, dataset=replace(sim.dataset, odometry=None))


def captured(
    sim: Simulation, errors: float, work: Path, jitter: float = 0.0, fmt: str = "lms200"
) -> Dataset:
    """`sim` written as an LMS-200 capture whose line flips `errors` of its bits, or as a ROS
    bag (`fmt` rosbag; `errors` 0), whose host's times spread by `jitter` scan periods (sd),
    imported; the simulation's truth beside it (a capture holds none)."""
    period = float(np.median(np.diff(sim.dataset.t)))
    if errors and fmt != "lms200":
        raise ValueError(f"{fmt} has no serial line to damage")
    damage: dict[str, Any] = {"bit_error_rate": errors} if fmt == "lms200" else {}
    write_simulation(
        sim, work / "capture", fmt, clock_jitter=jitter * period, seed=sim.seed, **damage
    )
    sources = [p for p in (work / "capture").iterdir() if p.suffix in {".lms", ".bag"}]
    ds = load(importers.import_log(fmt, sources, work / "imported"))
    return replace(ds, groundtruth=sim.dataset.groundtruth)


def simulated(
    worlds: tuple[int, ...],
    errors: tuple[float, ...],
    jitters: tuple[float, ...],
    kiss: bool,
    formats: tuple[str, ...] = ("lms200",),
) -> pd.DataFrame:
    rows = []
    for sim in simulations(worlds):
        for fmt, rate, jitter in itertools.product(formats, errors, jitters):
            if rate and fmt != "lms200":
                continue  # a bag has no serial line
            with tempfile.TemporaryDirectory() as tmp:
                ds = captured(sim, rate, Path(tmp), jitter, fmt)
                metrics = map_metrics(ds)
            truth = truth_poses(ds)
            assert truth is not None
            intervals = np.diff(ds.t) / np.median(np.diff(ds.t))
            row: dict[str, Any] = {
                "world": sim.scenario,
                "format": fmt,
                "scans": sim.dataset.n_scans,
                "seed": sim.seed,
                "bit_errors_per_million": round(rate * 1e6, 3),
                "clock_jitter": jitter,
                "lost": 1.0 - ds.n_scans / sim.dataset.n_scans,
                "longest": float(intervals.max()),
                "toolkit_map": metrics["ate"]["rmse"],
            }
            if kiss:
                row["kiss"] = ate(kiss_best(ds)[0], truth)
            rows.append(row)
            print_row(row)
    return pd.DataFrame(rows)


def _floats(text: str) -> tuple[float, ...]:
    """Comma-separated numbers."""
    return tuple(float(x) for x in text.split(","))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", type=int_ranges, default="466-473")
    parser.add_argument(
        "--errors",
        type=_floats,
        default=(0.0, 3e-5, 8e-5),
        help="bit error rates of the line, comma-separated",
    )
    parser.add_argument(
        "--jitter",
        type=_floats,
        default=(0.0,),
        help="spreads (sd, scan periods) of the host's clock, comma-separated",
    )
    parser.add_argument(
        "--formats",
        type=lambda text: tuple(text.split(",")),
        default=("lms200",),
        help="lms200 and/or rosbag (a bag without odometry: no line damage), comma-separated",
    )
    parser.add_argument("--no-kiss", dest="kiss", action="store_false", help="no KISS-ICP")
    parser.add_argument("--out", type=Path, default=Path("out/lost_telegrams.csv"))
    args = parser.parse_args()
    table = simulated(args.worlds, args.errors, args.jitter, args.kiss, args.formats)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out, index=False)
    numbers = [c for c in ("lost", "longest", "toolkit_map", "kiss") if c in table]
    by = ["world", "format", "scans", "bit_errors_per_million", "clock_jitter"]
    print(map_summary(table, by, numbers).to_string())


if __name__ == "__main__":
    main()
