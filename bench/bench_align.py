"""Table 2 protocol: Gaussian alignment (both Eq. 6 variants) against Open3D ICP on random 3D clouds.

As in the paper's random-cloud experiment: N points uniform in a 1 m cube, the copy shifted by
a random translation of up to 5 cm per axis with Gaussian noise (1 cm) added, 10 trials per
size; the Gaussian alignment knows the correspondence by index, ICP finds it by nearest
neighbours. Figures: median time per alignment and mean translation error over the trials.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from toolkit.align import gaussian, icp

SIZES = (100, 1000, 5000, 10_000)
TRIALS = 10
NOISE = 0.01
MAX_SHIFT = 0.05


def _timed(fn: Callable[[], np.ndarray], repeats: int) -> tuple[float, np.ndarray]:
    times = []
    shift = fn()
    for _ in range(repeats):
        t0 = time.perf_counter()
        shift = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), shift


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    sizes = SIZES[:2] if quick else SIZES
    trials = 3 if quick else TRIALS
    rng = np.random.default_rng(2014)
    rows: list[dict[str, object]] = []
    for n in sizes:
        stats: dict[str, tuple[list[float], list[float]]] = {
            k: ([], []) for k in ("gaussian", "gaussian-paper", "icp")
        }
        for _ in range(trials):
            prev = rng.uniform(0.0, 1.0, (n, 3))
            truth = rng.uniform(-MAX_SHIFT, MAX_SHIFT, 3)
            cur = prev + truth + rng.normal(0.0, NOISE, (n, 3))
            methods: dict[str, Callable[[], np.ndarray]] = {
                "gaussian": lambda c=cur, p=prev: gaussian(c, p).shift,
                "gaussian-paper": lambda c=cur, p=prev: gaussian(c, p, variant="paper").shift,
                "icp": lambda c=cur, p=prev: icp(c, p, max_distance=0.1).shift,
            }
            for name, fn in methods.items():
                seconds, shift = _timed(fn, 5 if name != "icp" else 1)
                stats[name][0].append(seconds)
                stats[name][1].append(float(np.linalg.norm(shift - truth)))
        icp_time = float(np.median(stats["icp"][0]))
        icp_err = float(np.mean(stats["icp"][1]))
        for name, (times, errors) in stats.items():
            t = float(np.median(times))
            rows.append(
                {
                    "name": name,
                    "points": n,
                    "trials": trials,
                    "seconds": t,
                    "error_m": float(np.mean(errors)),
                    "speedup_vs_icp": icp_time / t,
                    "error_vs_icp": float(np.mean(errors)) / icp_err,
                }
            )
    return rows
