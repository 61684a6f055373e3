"""Simulator speed: 10,000 scans of 181 beams (ray casting, laser and odometry models, truth)."""

from __future__ import annotations

import statistics
import time
from pathlib import Path

from toolkit.sim import simulate

SCANS = 10_000


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    repeats = 1 if quick else 3
    rows: list[dict[str, object]] = []
    for scenario in ("corridor", "building"):
        for units in ("cm", "mm"):  # 80 m mode: every wall in reach; 8 m mode: culled
            times = []
            for _ in range(repeats):
                start = time.perf_counter()
                sim = simulate(scenario, seed=0, scans=SCANS, units=units)
                times.append(time.perf_counter() - start)
            seconds = statistics.median(times)
            rows.append(
                {
                    "name": f"simulate {scenario} ({units} mode)",
                    "scans": sim.dataset.n_scans,
                    "beams": sim.dataset.n_beams,
                    "segments": len(sim.world.segments) if sim.world is not None else 0,
                    "repeats": repeats,
                    "seconds": round(seconds, 3),
                    "scans_per_s": round(SCANS / seconds),
                    "target_s": 10.0,
                }
            )
    return rows
