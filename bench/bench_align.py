"""Table 2: Gaussian alignment against Open3D ICP on random clouds, paper's protocol and dense.

The protocols are toolkit.align.protocol (the report runs the same): the methods timed
interleaved in one process, median time per alignment, mean and std of the translation
error over the trials, ratios to ICP; one table per protocol, the paper's first.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from toolkit.align.protocol import PROTOCOLS, SIZES, TRIALS, random_cloud_trials, summarize


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    summaries = []
    for protocol in PROTOCOLS:
        trials = random_cloud_trials(
            sizes=(100, 1000) if quick else SIZES,
            trials=3 if quick else TRIALS,
            protocol=protocol,
        )
        trials.to_csv(out / f"bench_align_trials_{protocol.name}.csv", index=False)
        summaries.append(summarize(trials))
    summary = pd.concat(summaries, ignore_index=True).rename(columns={"method": "name"})
    return summary.to_dict("records")  # type: ignore[return-value]
