"""Truth derived from the simulated path: training regions and sections.

A training region is `REGION_SCANS` consecutive scans that all carry one feature's label:
the middle of the first run of that label long enough to hold them (the most characteristic
view, away from the zone's edges). `regions.csv` gives them by timestamp, inclusive.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

REGION_SCANS = 10


def runs(labels: np.ndarray) -> list[tuple[str, int, int]]:
    """Maximal runs of equal labels as (label, first index, last index)."""
    labels = np.asarray(labels)
    if len(labels) == 0:
        return []
    change = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change - 1, [len(labels) - 1]])
    return [(str(labels[s]), int(s), int(e)) for s, e in zip(starts, ends, strict=True)]


def training_regions(
    t: np.ndarray, labels: np.ndarray, skip: tuple[str, ...] = ("none",), n: int = REGION_SCANS
) -> pd.DataFrame:
    """One region of `n` consecutive scans per label (except `skip`): feature, start, end."""
    rows = []
    seen: set[str] = set()
    for label, first, last in runs(labels):
        if label in seen or label in skip or last - first + 1 < n:
            continue
        seen.add(label)
        start = first + (last - first + 1 - n) // 2
        rows.append((label, float(t[start]), float(t[start + n - 1])))
    return pd.DataFrame(rows, columns=["feature", "start", "end"])


def sections(n_scans: int, n_sections: int) -> np.ndarray:
    """Section index per scan: `n_sections` equal consecutive parts (-1 everywhere if 0)."""
    if n_sections <= 0:
        return np.full(n_scans, -1, dtype=np.int64)
    return (np.arange(n_scans, dtype=np.int64) * n_sections) // max(n_scans, 1)
