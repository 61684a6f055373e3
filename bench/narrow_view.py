"""Maps of LMS-200 captures without odometry in the scanner's narrow (100-degree) modes.

    python -m bench.narrow_view --worlds 514-521                 # KISS-ICP beside
    python -m bench.narrow_view --worlds 0-7 --no-kiss --views 100/101,100/201

The LMS-200 scans 180 degrees at 1 or 0.5 degrees a beam (181, 361 beams) or 100 degrees at
1, 0.5 or 0.25 (101, 201, 401). The simulator's corridor and building (2,000 scans each,
world = seed) are simulated in each view (`--views`, degrees/beams), written as raw LMS-200
captures without odometry and imported as a user would. Without odometry nothing but the
scans says how the robot moved, and a narrow view holds less of the walls beside and behind
it. Per run: `toolkit map` (`toolkit.mapping.map_run`, ATE and before loops) and, unless
`--no-kiss`, KISS-ICP with its constant velocity (best of voxel 0.1 / 0.3 m). docs/maps.md,
"Methods".
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from bench.bench_slam import ate, kiss_best, map_metrics, map_summary, print_row
from bench.lost_telegrams import captured
from toolkit.poses import truth_poses
from toolkit.sim import simulate
from toolkit.typed import int_ranges

SCENARIOS = ("corridor", "building")
SCANS = 2000
#: the scanner's modes measured by default: degrees, beams
VIEWS = ((180, 181), (100, 101), (100, 201))


def _views(text: str) -> tuple[tuple[int, int], ...]:
    """Comma-separated degrees/beams pairs: "180/181,100/201"."""
    pairs = [part.split("/") for part in text.split(",")]
    return tuple((int(fov), int(beams)) for fov, beams in pairs)


def measured(
    worlds: tuple[int, ...], views: tuple[tuple[int, int], ...], kiss: bool
) -> pd.DataFrame:
    """One row per scenario, world and view: the map's ATE (and KISS-ICP's)."""
    rows = []
    for scenario in SCENARIOS:
        for seed in worlds:
            for fov, beams in views:
                sim = simulate(scenario, seed=seed, scans=SCANS, fov_deg=fov, beams=beams)
                sim = replace(sim, dataset=replace(sim.dataset, odometry=None))
                with tempfile.TemporaryDirectory() as tmp:
                    ds = captured(sim, 0.0, Path(tmp))
                    metrics = map_metrics(ds)
                row: dict[str, Any] = {
                    "world": scenario,
                    "seed": seed,
                    "fov_deg": fov,
                    "beams": beams,
                    "toolkit_map": metrics["ate"]["rmse"],
                    "before_loops": metrics["before_loops"]["ate"]["rmse"],
                }
                if kiss:
                    truth = truth_poses(ds)
                    assert truth is not None
                    row["kiss"] = ate(kiss_best(ds)[0], truth)
                rows.append(row)
                print_row(row)
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", type=int_ranges, default="514-521")
    parser.add_argument(
        "--views",
        type=_views,
        default=VIEWS,
        help="the scanner's modes, degrees/beams, comma-separated (e.g. 180/181,100/201)",
    )
    parser.add_argument("--no-kiss", dest="kiss", action="store_false", help="no KISS-ICP")
    parser.add_argument("--out", type=Path, default=Path("out/narrow_view.csv"))
    args = parser.parse_args()
    table = measured(args.worlds, args.views, args.kiss)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out, index=False)
    numbers = [c for c in ("toolkit_map", "before_loops", "kiss") if c in table]
    by = ["world", "fov_deg", "beams"]
    print(map_summary(table, by, numbers).to_string())


if __name__ == "__main__":
    main()
