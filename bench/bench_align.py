"""Table 2 protocol: Gaussian alignment (both Eq. 6 variants) against Open3D ICP on random 3D clouds.

The protocol is toolkit.align.protocol (the report runs the same): median time per alignment,
mean and std of the translation error over the trials, ratios to ICP.
"""

from __future__ import annotations

from pathlib import Path

from toolkit.align.protocol import SIZES, TRIALS, random_cloud_trials, summarize


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    trials = random_cloud_trials(
        sizes=(100, 1000) if quick else SIZES, trials=3 if quick else TRIALS
    )
    trials.to_csv(out / "bench_align_trials.csv", index=False)
    summary = summarize(trials).rename(columns={"method": "name"})
    return summary.to_dict("records")  # type: ignore[return-value]
