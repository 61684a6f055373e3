"""The paper's random-cloud experiment (its Table 2, Fig. 4-5): Gaussian alignment against ICP.

N points uniform in a 1 m cube; the copy is shifted by a random translation of up to 5 cm per
axis and Gaussian noise (1 cm) is added; 10 trials per size. The Gaussian alignment knows the
correspondence by index, ICP finds it by nearest neighbours. Used by `make bench` and by the
report, so both measure the same thing.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from toolkit.align.baselines import icp
from toolkit.align.gaussian import gaussian

SIZES = (100, 500, 1000, 5000, 10_000)  # the paper's
TRIALS = 10
NOISE = 0.01
MAX_SHIFT = 0.05
METHODS = ("gaussian", "gaussian-paper", "icp")


def _aligner(method: str) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    if method == "gaussian":
        return lambda cur, prev: gaussian(cur, prev).shift
    if method == "gaussian-paper":
        return lambda cur, prev: gaussian(cur, prev, variant="paper").shift
    if method == "icp":
        return lambda cur, prev: icp(cur, prev, max_distance=0.1).shift
    raise ValueError(f"unknown method {method!r}; known: {', '.join(METHODS)}")


def random_cloud_trials(
    sizes: Sequence[int] = SIZES,
    trials: int = TRIALS,
    methods: Sequence[str] = METHODS,
    seed: int = 2014,
    repeats: int = 5,
) -> pd.DataFrame:
    """One row per method, size and trial: the time (median of `repeats` calls after a warm-up;
    ICP once) and the translation error of the estimate."""
    rng = np.random.default_rng(seed)
    aligners = {m: _aligner(m) for m in methods}
    rows = []
    for n in sizes:
        for trial in range(trials):
            prev = rng.uniform(0.0, 1.0, (n, 3))
            truth = rng.uniform(-MAX_SHIFT, MAX_SHIFT, 3)
            cur = prev + truth + rng.normal(0.0, NOISE, (n, 3))
            for method, align in aligners.items():
                shift = align(cur, prev)
                times = []
                for _ in range(1 if method == "icp" else repeats):
                    t0 = time.perf_counter()
                    shift = align(cur, prev)
                    times.append(time.perf_counter() - t0)
                rows.append(
                    {
                        "method": method,
                        "points": n,
                        "trial": trial,
                        "seconds": float(np.median(times)),
                        "error_m": float(np.linalg.norm(shift - truth)),
                    }
                )
    return pd.DataFrame(rows)


def summarize(trials: pd.DataFrame) -> pd.DataFrame:
    """Per method and size: trials, median time, mean and std of the error, ratios to ICP."""
    summary = (
        trials.groupby(["points", "method"], sort=True)
        .agg(
            trials=("trial", "count"),
            seconds=("seconds", "median"),
            error_m=("error_m", "mean"),
            error_std_m=("error_m", "std"),
        )
        .reset_index()
    )
    if (summary["method"] == "icp").any():
        icp_rows = summary[summary["method"] == "icp"].set_index("points")
        summary["speedup_vs_icp"] = summary["points"].map(icp_rows["seconds"]) / summary["seconds"]
        summary["error_vs_icp"] = summary["error_m"] / summary["points"].map(icp_rows["error_m"])
    return summary
