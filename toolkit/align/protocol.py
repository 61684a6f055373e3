"""The paper's random-cloud experiment (its Table 2, Fig. 4-5): Gaussian alignment against ICP.

Two protocols, both used by `make bench` and by the report, so both measure the same thing:

- `PAPER`, the paper's own: "each coordinate point was between 0 and 100" with Gaussian
  noise. N points uniform in [0, 100]^3 (m); the copy is shifted by up to 1 m per axis and
  Gaussian noise of 5 cm is added; 10 trials per size.
- `DENSE`, the project's earlier one: N points in a 1 m cube, shifted by up to 5 cm per
  axis, 1 cm noise. Dense and noisy, where ICP's nearest neighbours are often wrong and slow.

The Gaussian alignment knows the correspondence by index, ICP (Open3D point-to-point) finds
it by nearest neighbours within twice the largest shift. Both run on one thread (Open3D's
OpenMP is limited to one, as the Gaussian alignment uses one: a per-core comparison, and one
that busy cores do not distort: with its two threads on two loaded cores Open3D spins, 600 ms
per 10,000-point alignment instead of tens). The methods are timed interleaved
in one process: each gets the same untimed warm-up call per size, then trial by trial they
alternate (the order reversed every other trial), each timed the same number of calls on
the same clouds; a trial's time is the median of its calls, a size's the median of its
trials. The error of each method is the distance of its estimate from the true shift.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from toolkit.align.baselines import icp, one_openmp_thread
from toolkit.align.gaussian import gaussian

SIZES = (100, 500, 1000, 5000, 10_000)  # the paper's
TRIALS = 10
REPEATS = 3  # timed calls per method and trial (the median is kept)
METHODS = ("gaussian", "gaussian-paper", "icp")


@dataclass(frozen=True)
class Protocol:
    """A random-cloud protocol: where the points lie, how far the copy moves, its noise."""

    name: str
    title: str
    extent: float  # m: coordinates uniform in [0, extent] on each axis
    max_shift: float  # m: the true shift is uniform in [-max_shift, max_shift] per axis
    noise: float  # m: standard deviation of the Gaussian noise per coordinate

    @property
    def icp_max_distance(self) -> float:
        """ICP's correspondence distance: twice the largest shift per axis (covers any shift
        and the noise on top)."""
        return 2.0 * self.max_shift


PAPER = Protocol("paper", "the paper's: coordinates 0-100 m, shift up to 1 m, 5 cm noise", 100.0, 1.0, 0.05)  # fmt: skip
DENSE = Protocol("dense", "dense cube: coordinates 0-1 m, shift up to 5 cm, 1 cm noise", 1.0, 0.05, 0.01)  # fmt: skip
PROTOCOLS = (PAPER, DENSE)


def _aligner(method: str, protocol: Protocol) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    if method == "gaussian":
        return lambda cur, prev: gaussian(cur, prev).shift
    if method == "gaussian-paper":
        return lambda cur, prev: gaussian(cur, prev, variant="paper").shift
    if method == "icp":
        reach = protocol.icp_max_distance
        return lambda cur, prev: icp(cur, prev, max_distance=reach).shift
    raise ValueError(f"unknown method {method!r}; known: {', '.join(METHODS)}")


def random_cloud_trials(
    sizes: Sequence[int] = SIZES,
    trials: int = TRIALS,
    methods: Sequence[str] = METHODS,
    seed: int = 2014,
    repeats: int = REPEATS,
    protocol: Protocol = PAPER,
) -> pd.DataFrame:
    """One row per method, size and trial: the time (median of `repeats` calls, the methods
    interleaved, see the module docstring) and the translation error of the estimate."""
    with one_openmp_thread():  # both methods on one thread
        return pd.DataFrame(_trials(sizes, trials, methods, seed, repeats, protocol))


def _trials(
    sizes: Sequence[int],
    trials: int,
    methods: Sequence[str],
    seed: int,
    repeats: int,
    protocol: Protocol,
) -> list[dict[str, object]]:
    rng = np.random.default_rng(seed)
    aligners = {m: _aligner(m, protocol) for m in methods}
    rows: list[dict[str, object]] = []
    for n in sizes:
        clouds = []
        for _ in range(trials):
            prev = rng.uniform(0.0, protocol.extent, (n, 3))
            truth = rng.uniform(-protocol.max_shift, protocol.max_shift, 3)
            cur = prev + truth + rng.normal(0.0, protocol.noise, (n, 3))
            clouds.append((cur, prev, truth))
        for align in aligners.values():  # the same warm-up for every method
            align(*clouds[0][:2])
        for trial, (cur, prev, truth) in enumerate(clouds):
            order = list(aligners) if trial % 2 == 0 else list(reversed(aligners))
            for method in order:
                align = aligners[method]
                times = []
                for _ in range(repeats):
                    t0 = time.perf_counter()
                    shift = align(cur, prev)
                    times.append(time.perf_counter() - t0)
                rows.append(
                    {
                        "protocol": protocol.name,
                        "method": method,
                        "points": n,
                        "trial": trial,
                        "seconds": float(np.median(times)),
                        "error_m": float(np.linalg.norm(shift - truth)),
                    }
                )
    return rows


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
    if "protocol" in trials:
        summary.insert(0, "protocol", trials["protocol"].iloc[0] if len(trials) else "")
    if (summary["method"] == "icp").any():
        icp_rows = summary[summary["method"] == "icp"].set_index("points")
        summary["speedup_vs_icp"] = summary["points"].map(icp_rows["seconds"]) / summary["seconds"]
        summary["error_vs_icp"] = summary["error_m"] / summary["points"].map(icp_rows["error_m"])
    return summary
