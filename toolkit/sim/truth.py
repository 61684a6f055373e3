"""Truth derived from the simulated path: training regions and sections.

A feature is taught by `REGION_SCANS` scans of its first occurrence (its first run of labels
long enough to hold them), in `REGION_PARTS` spans of consecutive scans centred at equal
steps of the distance driven through it: with two, a quarter and three quarters of the way,
one where the place begins and one where it ends. A place looks different from its two ends
(a doorway ahead, then beside; a corner arrived at, then left), and ten scans in one burst
at its middle, 0.4 m of path, show neither. Steps are in metres driven, not in scans, as a
user picks them on the map: in a corner the robot turns on the spot for half its scans, and
by scan count both spans would fall in the crossing, none on the way in or out.
`regions.csv` gives the spans by timestamp, inclusive, a row each.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

REGION_SCANS = 10
REGION_PARTS = 2


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
    t: np.ndarray,
    labels: np.ndarray,
    skip: tuple[str, ...] = ("none",),
    n: int = REGION_SCANS,
    parts: int | dict[str, int] = REGION_PARTS,
    along: np.ndarray | None = None,
) -> pd.DataFrame:
    """`n` training scans per label (except `skip`) in `parts` spans (or per label, a dict;
    labels it does not name: `REGION_PARTS`): feature, start, end.
    The spans are centred at equal steps of `along` (per scan, e.g. `toolkit.dataset.path_distance`; by
    default the scan index)."""
    along = np.arange(len(t), dtype=np.float64) if along is None else np.asarray(along)
    rows = []
    seen: set[str] = set()
    for label, first, last in runs(labels):
        if label in seen or label in skip or last - first + 1 < n:
            continue
        seen.add(label)
        way = along[first : last + 1] - along[first]
        if not way[-1] > 0:  # standing still all along: by scan
            way = np.arange(last - first + 1, dtype=np.float64)
        k_parts = parts.get(label, REGION_PARTS) if isinstance(parts, dict) else parts
        sizes = np.full(k_parts, n // k_parts) + (np.arange(k_parts) < n % k_parts)
        for k, size in enumerate(sizes):
            centre = first + int(np.searchsorted(way, (2 * k + 1) * way[-1] / (2 * k_parts)))
            start = int(np.clip(centre - size // 2, first, last + 1 - size))
            rows.append((label, float(t[start]), float(t[start + size - 1])))
    return pd.DataFrame(rows, columns=["feature", "start", "end"])


def sections(n_scans: int, n_sections: int) -> np.ndarray:
    """Section index per scan: `n_sections` equal consecutive parts (-1 everywhere if 0)."""
    if n_sections <= 0:
        return np.full(n_scans, -1, dtype=np.int64)
    return (np.arange(n_scans, dtype=np.int64) * n_sections) // max(n_scans, 1)
