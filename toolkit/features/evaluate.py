"""Scoring on the simulator's labelled logs, and the ablation table: the paper's literal
per-scan model, then each improvement added in turn, every row measured the same way
(train on the simulator's regions: 10 scans per feature, 5 where the place begins and 5
where it ends; score all other scans against the true labels). A last row scores the best
option on the older protocol, one 10-scan burst at each place's middle.

    python -m toolkit.features.evaluate [--seed N [N ...]] [--recall] [--out table.md]
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
from toolkit.features.model import PAPER, SURROUNDINGS, Config, fit
from toolkit.features.regions import spans_from_frame, training_indices
from toolkit.sim import Simulation
from toolkit.sim.truth import REGION_PARTS, training_regions

# The ablation: each row adds one decision to the one before; the default row is Config().
FULL = Config()
STREAM = dataclasses.replace(FULL, smoothing="forward", evidence_length=None)
AROUND = dataclasses.replace(FULL, none_model="surroundings")
ALIKE = dataclasses.replace(SURROUNDINGS, lateral_weight=0.0)  # every beam alike
LATERAL = dataclasses.replace(SURROUNDINGS, lateral_weight=1.0)
LATERAL2 = dataclasses.replace(SURROUNDINGS, lateral_weight=2.0)
ABLATION: list[tuple[str, Config]] = [
    ("paper: per-scan Gaussian, Eq. 8-9 literal", PAPER),
    ("+ no-return as a Bernoulli per beam", dataclasses.replace(PAPER, no_return=True)),
    ("+ variance floor (sensor noise)", dataclasses.replace(PAPER, no_return=True, noise_sigma=FULL.noise_sigma)),
    ("+ none class (background of the log)", dataclasses.replace(STREAM, robust=0.0, shifts=0, temperature="none", smoothing="none")),
    ("+ robust beams (mixture with the background)", dataclasses.replace(STREAM, shifts=0, temperature="none", smoothing="none")),
    ("+ beam-shifted training copies", dataclasses.replace(STREAM, temperature="none", smoothing="none")),
    ("+ temperature (leave-one-out design effect)", dataclasses.replace(STREAM, smoothing="none")),
    ("+ HMM forward filter along the path (Eq. 7): streaming", STREAM),
    ("+ forward-backward (offline: the whole log)", dataclasses.replace(STREAM, smoothing="forward-backward")),
    ("+ evidence length 0.5 m", FULL),
    ("option: + none = the features' surroundings", AROUND),
    ("option: + strict returns", dataclasses.replace(AROUND, strict_returns=True)),
    ("option: + evidence length 0.15 m (--lateral 0)", ALIKE),
    ("option: + lateral beams, |sin(bearing)| (--lateral 1)", LATERAL),
    ("option: lateral beams, |sin(bearing)|^2 (--lateral 2)", LATERAL2),
    ("option: lateral weight by leave-one-span-out (--none-model surroundings)", SURROUNDINGS),
    ("alternative: forward filter with evidence length 0.5 m", dataclasses.replace(FULL, smoothing="forward")),
    ("alternative: strict returns alone", dataclasses.replace(FULL, strict_returns=True)),
    ("alternative: default + lateral beams", dataclasses.replace(FULL, lateral_weight=1.0)),
]  # fmt: skip
BURST = "protocol: --none-model surroundings, taught by one 10-scan burst per feature"


@dataclass
class Score:
    balanced_accuracy: float
    ece: float
    accuracy: float
    scans: int
    recall: dict[str, float]
    temperature: float
    lateral_weight: float
    seconds: float


def score(
    scenario: str,
    config: Config,
    seed: int = 0,
    sim: Simulation | None = None,
    parts: int = REGION_PARTS,
) -> Score:
    """Train on the simulator's regions (`parts` spans per feature), classify the whole log,
    score the other scans."""
    if sim is None:
        from toolkit.sim import simulate

        sim = simulate(scenario, seed=seed)
    ds = sim.dataset
    regions = training_regions(ds.t, sim.labels, parts=parts, along=sim.distance())
    spans = spans_from_frame(regions, ds.t)
    training = training_indices(spans)
    t0 = time.perf_counter()
    model = fit(ds.ranges, ds.laser, training, config, spans)
    if ds.groundtruth is None:
        raise ValueError("the simulation has no ground truth")
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
        lateral_weight=float(model.config.lateral_weight or 0.0),
        seconds=seconds,
    )


def ablation(
    seed: int | tuple[int, ...] = 0, scenarios: tuple[str, ...] = ("corridor", "building")
) -> pd.DataFrame:
    """One row per configuration: balanced accuracy and ECE per scenario (and seed)."""
    from toolkit.sim import simulate

    seeds = (seed,) if isinstance(seed, int) else tuple(seed)
    sims = {(s, k): simulate(s, seed=k) for s in scenarios for k in seeds}
    rows = []
    for name, config, parts in [
        *((n, c, REGION_PARTS) for n, c in ABLATION),
        (BURST, SURROUNDINGS, 1),
    ]:
        row: dict[str, Any] = {"model": name + (" (default)" if config == FULL else "")}
        for s in scenarios:
            for k in seeds:
                r = score(s, config, k, sims[s, k], parts)
                tag = s if len(seeds) == 1 else f"{s} s{k}"
                row[f"{tag} BA"] = round(r.balanced_accuracy, 3)
                row[f"{tag} ECE"] = round(r.ece, 3)
        rows.append(row)
    return pd.DataFrame(rows)


RECALL_ROWS = {
    "default": FULL,
    "--none-model surroundings --lateral 0": ALIKE,
    "--none-model surroundings --lateral 1": LATERAL,
    "--none-model surroundings (lateral auto)": SURROUNDINGS,
}


def recall_table(
    configs: dict[str, Config] | None = None,
    seed: int = 0,
    scenarios: tuple[str, ...] = ("corridor", "building"),
) -> pd.DataFrame:
    """Recall per true class, one row per scenario and configuration (by default the
    default, the surroundings option and the lateral option)."""
    from toolkit.sim import simulate

    rows = []
    for s in scenarios:
        sim = simulate(s, seed=seed)  # once per scenario, for every configuration
        for name, config in (configs or RECALL_ROWS).items():
            r = score(s, config, seed, sim)
            rows.append(
                {"scenario": s, "model": name, **{k: round(v, 3) for k, v in r.recall.items()}}
            )
    return pd.DataFrame(rows).astype(object).fillna("")


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
    parser.add_argument("--seed", type=int, nargs="+", default=[0], help="one or more seeds")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--recall", action="store_true", help="also recall per class")
    args = parser.parse_args()
    text = markdown(ablation(tuple(args.seed)))
    if args.recall:
        text += "\n\n" + markdown(recall_table(seed=args.seed[0]))
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
