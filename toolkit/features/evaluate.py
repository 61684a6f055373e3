"""Scoring on the simulator's labelled logs, and the ablation table: the paper's literal
per-scan model, then each improvement added in turn, every row measured the same way
(train on the simulator's 10-scan regions, score all other scans against the true labels).

    python -m toolkit.features.evaluate [--seed N] [--out table.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from toolkit.features.classify import classify
from toolkit.features.metrics import (
    balanced_accuracy,
    expected_calibration_error,
    per_class_recall,
)
from toolkit.features.model import PAPER, Config, fit
from toolkit.features.regions import spans_from_frame, training_indices

# The ablation: each row adds one decision to the one before; the last row is Config().
FULL = Config()
ABLATION: list[tuple[str, Config]] = [
    ("paper: per-scan Gaussian, Eq. 8-9 literal", PAPER),
    ("+ no-return as a Bernoulli per beam", dataclasses.replace(PAPER, no_return=True)),
    ("+ variance floor (sensor noise)", dataclasses.replace(PAPER, no_return=True, noise_sigma=FULL.noise_sigma)),
    (
        "+ none class (background of the log)",
        dataclasses.replace(FULL, robust=0.0, shifts=0, temperature="none", smoothing="none"),
    ),
    ("+ robust beams (mixture with the background)", dataclasses.replace(FULL, shifts=0, temperature="none", smoothing="none")),
    ("+ beam-shifted training copies", dataclasses.replace(FULL, temperature="none", smoothing="none")),
    ("+ temperature (leave-one-out design effect)", dataclasses.replace(FULL, smoothing="none")),
    ("+ HMM forward filter along the path (Eq. 7): default", FULL),
    ("alternative: forward-backward smoothing", dataclasses.replace(FULL, smoothing="forward-backward")),
    ("alternative: robust weight 0.3, no smoothing", dataclasses.replace(FULL, robust=0.3, smoothing="none")),
]  # fmt: skip


@dataclass
class Score:
    balanced_accuracy: float
    ece: float
    accuracy: float
    scans: int
    recall: dict[str, float]
    temperature: float
    seconds: float


def score(scenario: str, config: Config, seed: int = 0, sim: Any = None) -> Score:
    """Train on the simulator's regions, classify the whole log, score the other scans."""
    if sim is None:
        from toolkit.sim import simulate

        sim = simulate(scenario, seed=seed)
    ds = sim.dataset
    spans = spans_from_frame(sim.regions, ds.t)
    training = training_indices(spans)
    t0 = time.perf_counter()
    model = fit(ds.ranges, ds.laser, training, config, spans)
    poses = ds.groundtruth[["x", "y", "theta"]].to_numpy()
    labels = classify(model, ds.ranges, poses)
    seconds = time.perf_counter() - t0
    test = np.ones(len(ds.t), dtype=bool)
    test[np.concatenate(list(training.values()))] = False
    truth, predicted = np.asarray(sim.labels)[test], labels.label[test]
    correct = truth == predicted
    return Score(
        balanced_accuracy=balanced_accuracy(truth, predicted),
        ece=expected_calibration_error(labels.confidence[test], correct),
        accuracy=float(correct.mean()),
        scans=int(test.sum()),
        recall=per_class_recall(truth, predicted),
        temperature=model.temperature,
        seconds=seconds,
    )


def ablation(seed: int = 0, scenarios: tuple[str, ...] = ("corridor", "building")) -> pd.DataFrame:
    """One row per configuration: balanced accuracy and ECE per scenario."""
    from toolkit.sim import simulate

    sims = {s: simulate(s, seed=seed) for s in scenarios}
    rows = []
    for name, config in ABLATION:
        row: dict[str, Any] = {"model": name}
        for s in scenarios:
            r = score(s, config, seed, sims[s])
            row[f"{s} BA"] = round(r.balanced_accuracy, 3)
            row[f"{s} ECE"] = round(r.ece, 3)
        rows.append(row)
    return pd.DataFrame(rows)


def markdown(table: pd.DataFrame) -> str:
    """A pipe table (no extra dependency)."""
    cols = [str(c) for c in table.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for row in table.itertuples(index=False):
        lines.append(
            "| " + " | ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in row) + " |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    text = markdown(ablation(args.seed))
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
