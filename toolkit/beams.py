"""Beams that do not see the world: the robot's own body (a bracket, a wheel, a mast at the
edge of the laser's view) or a stuck beam read the same range while the robot turns.

Such returns move with the robot, so every matcher reads them as "no motion": on the
simulated corridor, 20 beams at each edge of a 181-beam scan fixed at 0.3 m take the mapper
from 0.11 m to 0.78 m of ATE, 40 to 33 m (the odometry alone: 3.3 m). A world surface seen
by one beam changes its range when the robot turns; these do not. `fixed_beams` finds them
from the odometry's turns, or in a log without odometry (a raw LMS-200 capture) from scans far
apart in time (docs/maps.md, "Beams that see the robot"); `without_beams` leaves them out (no
return), as a laser filter would. `share_beyond_reach` tells a log whose ranges
are in cm or mm: every return beyond any laser's reach.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from toolkit.dataset import Dataset
from toolkit.se2 import wrap

TURNS = (0.5, 1.2)  # rad: scans compared across turns of about these (both must agree) ...
SAME = 0.03  # m: ... a beam's ranges that differ by no more than this are the same ...
AGREE = 0.9  # ... and a beam whose ranges are the same in this share of the pairs is fixed
NEAR = 2.0  # m: only beams whose median range is within this (the robot's own body) ...
MIN_PAIRS = 8  # fewer pairs with a return on the beam (per turn): not judged
MOVE = 2.0  # m: pairs whose odometry moved further than this are not compared (two
# corridors of one width look alike from their middles whatever the turn between them)
CHANGED = 0.3  # pairs in which fewer beams than this share changed are not compared (the
# odometry turned, the scan did not: a wheel's slip)
MAX_PAIRS = 2000  # pairs compared per turn, evenly spread over the log (memory)
# without odometry: scans a quarter and half the log apart are compared (both must agree) ...
APART = (4, 2)
# ... and a beam is fixed when its ranges are the same in this share of the pairs. Stricter
# than AGREE: nothing says the robot turned between the two scans, and on the simulated
# corridor the wall beside a robot that drives straight along it reads the same in 0.88 of
# them; a body seen with 1 cm of range noise reads the same in about 0.97
APART_AGREE = 0.95
SAMPLE = 2000  # scans, evenly spread, that give a beam's median and the returns' reach


def _sample(ranges: np.ndarray) -> np.ndarray:
    """At most about SAMPLE scans of `ranges`, evenly spread (a view: nothing copied)."""
    return ranges[:: max(1, len(ranges) // SAMPLE)]


def _turn_pairs(odometry: np.ndarray, turn: float) -> tuple[np.ndarray, np.ndarray]:
    """Scan pairs (i, j) of `odometry` (S x 3): j the first scan after i by `turn` rad of
    turning, whose heading is at least 0.8 `turn` from i's (a wiggle turns without turning
    away) and which lies within MOVE m of i; at most MAX_PAIRS, evenly spread."""
    heading = odometry[:, 2]
    turned = np.concatenate([[0.0], np.cumsum(np.abs(wrap(np.diff(heading))))])
    j = np.searchsorted(turned, turned + turn)
    i = np.nonzero(j < len(heading))[0]
    j = j[i]
    away = np.abs(wrap(heading[j] - heading[i])) >= 0.8 * turn
    away &= np.hypot(*(odometry[j, :2] - odometry[i, :2]).T) <= MOVE
    i, j = i[away], j[away]
    if len(i) > MAX_PAIRS:
        pick = np.linspace(0, len(i) - 1, MAX_PAIRS).astype(np.int64)
        i, j = i[pick], j[pick]
    return i, j


def _apart_pairs(scans: int, part: int) -> tuple[np.ndarray, np.ndarray]:
    """Scan pairs (i, i + scans // part) of a log of `scans` scans; at most MAX_PAIRS, evenly
    spread."""
    gap = scans // part
    i = np.arange(scans - gap if gap > 0 else 0)
    if len(i) > MAX_PAIRS:
        i = i[np.linspace(0, len(i) - 1, MAX_PAIRS).astype(np.int64)]
    return i, i + gap


def fixed_beams(ranges: np.ndarray, odometry: np.ndarray | None) -> np.ndarray:
    """The beams (ascending indices) of `ranges` (S x B) within NEAR m (median) whose range
    stays within SAME m in AGREE of the scan pairs a turn of each of TURNS apart and within
    MOVE m of each other (`odometry`: S x 3, at the scans). A log that never turns that far
    gives none. Without odometry (None), in APART_AGREE of the pairs a quarter and half the
    log apart in time. Either way only pairs in which CHANGED of the beams changed count:
    a robot that stood still tells nothing.

    Far beams are kept whatever they read: acapulco's last beam reads 50.0 m in every scan
    (a stuck beam, or the log's stand-in for no return), and the mapper's poses there were
    judged with it."""
    with warnings.catch_warnings():  # a beam without a return: its median is NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        median = np.nanmedian(_sample(ranges), axis=0)
    fixed = median <= NEAR
    if odometry is None:
        pairs = [_apart_pairs(len(ranges), part) for part in APART]
        agree = APART_AGREE
    else:
        odometry = np.asarray(odometry, dtype=np.float64)
        pairs = [_turn_pairs(odometry, turn) for turn in TURNS]
        agree = AGREE
    for i, j in pairs:
        a, b = ranges[i], ranges[j]
        seen = np.isfinite(a) & np.isfinite(b)
        alike = seen & (np.abs(a - b) <= SAME)
        changed = (seen & ~alike).sum(axis=1) >= CHANGED * np.maximum(seen.sum(axis=1), 1)
        seen &= changed[:, None]
        same = (alike & seen).sum(axis=0)
        count = seen.sum(axis=0)
        fixed &= (count >= MIN_PAIRS) & (same >= agree * np.maximum(count, 1))
    return np.nonzero(fixed)[0]


def without_beams(ds: Dataset, beams: np.ndarray) -> Dataset:
    """`ds` with `beams` read as no return (NaN); `ds` itself when there are none (no copy)."""
    if len(beams) == 0:
        return ds
    ranges = ds.ranges.copy()
    ranges[:, beams] = np.nan
    return replace(ds, ranges=ranges)


FAR = 100.0  # m: beyond any 2D laser's reach (an LMS-200's is 80 m)


def share_beyond_reach(ranges: np.ndarray) -> float:
    """The share of the returns of `ranges` (S x B; `_sample`'s scans) beyond FAR m: most of
    them there means ranges in cm or mm, which no matcher reads."""
    sample = _sample(ranges)
    seen = np.isfinite(sample)
    count = int(seen.sum())
    return float((sample[seen] > FAR).sum() / count) if count else 0.0


def beam_spans(beams: list[int]) -> str:
    """Beam indices (ascending) as runs, e.g. "0-19, 161-180"."""
    runs: list[list[int]] = []
    for b in beams:
        if runs and b == runs[-1][1] + 1:
            runs[-1][1] = b
        else:
            runs.append([b, b])
    return ", ".join(f"{s}" if s == e else f"{s}-{e}" for s, e in runs)
