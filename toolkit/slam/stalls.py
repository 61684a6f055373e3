"""Odometry that stands still while the robot moves: an encoder that stalled, or an odometry
stream that starts late or stops early (its poses are held at the ends, `PoseStream.at`).

Every matcher that the odometry seeds takes such a stretch as "no motion", and with the
prior tight on a step that did not move, it keeps it: on the simulated corridor (2,000
scans), odometry frozen over the middle third maps 19.5 m off, where the same log without
any odometry maps to 0.1 m. The scans say that the robot moved, so each stretch of at least
`MIN_STILL` scans whose odometry does not move is mapped as a log without odometry (the
mapper's own no-odometry path, `slam_trajectory`: constant velocity, the keyframe front end,
loops). Where that map moves the robot `MOVED` m or turns it `TURNED` rad between the
stretch's first scan and its last, the stretch's odometry steps are replaced by the map's;
the steps after it are the odometry's, continued from the mended end (`mend_stalls`).

A robot that really stood still maps within a few millimetres of where it stood (the real
logs' stops: at most 7 mm over 4-22 scans), far below `MOVED`: its odometry is kept as logged.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from toolkit import se2
from toolkit.dataset import Dataset, PoseStream
from toolkit.poses import compose_steps

if TYPE_CHECKING:
    from collections.abc import Callable

    from toolkit.align import scan as sc
    from toolkit.slam.pipeline import SlamConfig

MIN_STILL = 10  # scans: a shorter stretch of still odometry is not looked at (a pause)
STILL = 1e-4  # m and rad per scan: an odometry step within both has not moved
MOVED = 0.3  # m: a stretch mapped this far from its first scan to its last moved ...
TURNED = 0.3  # rad: ... or turned this much: its odometry stalled
LEAD = 10  # odometry steps before a stretch whose median motion starts its map (the robot
# moves on as it did; measured from the stretch's own scans, the start velocity of a bare
# corridor is often "not moved": the building's middle third mapped 2.4-3.2 m short, seeded
# 1.2-1.9 m)


@dataclass(frozen=True)
class Stall:
    """Scans `first`..`last` (inclusive), whose odometry stood still while the scans, mapped
    without it, moved the robot `moved` m and turned it `turned` rad."""

    first: int
    last: int
    moved: float
    turned: float

    def to_dict(self) -> dict[str, float | int]:
        return {
            "first": self.first,
            "last": self.last,
            "moved_m": round(self.moved, 3),
            "turned_rad": round(self.turned, 3),
        }


def still_stretches(odometry: np.ndarray, least: int = MIN_STILL) -> list[tuple[int, int]]:
    """The stretches (first, last scan, inclusive) of at least `least` scans over which the
    odometry (S x 3, at the scan times) does not move: every step within `STILL`."""
    if len(odometry) < 2:
        return []
    steps = se2.between(odometry[:-1], odometry[1:])
    still = (np.hypot(steps[:, 0], steps[:, 1]) < STILL) & (np.abs(steps[:, 2]) < STILL)
    edges = np.diff(np.concatenate([[0], still.astype(np.int8), [0]]))
    starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
    # steps starts..ends-1 are still: scans starts..ends
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True) if b - a + 1 >= least]


def _lead(steps: np.ndarray, first: int) -> np.ndarray | None:
    """The odometry's median motion per scan over the `LEAD` steps before scan `first`, or
    None where there are none or the robot stood (the map's start pass measures it)."""
    lead = steps[max(first - LEAD, 0) : first]
    if not len(lead):
        return None
    velocity = np.asarray(np.median(lead, axis=0))
    return (
        velocity if np.hypot(velocity[0], velocity[1]) >= 1e-3 or abs(velocity[2]) >= 1e-3 else None
    )


def mend_stalls(
    ds: Dataset,
    odometry: np.ndarray,
    stretches: list[tuple[int, int]],
    config: sc.MatchConfig | None = None,
    slam: SlamConfig | None = None,
    progress: Callable[[int], object] | None = None,
) -> tuple[Dataset, list[Stall]]:
    """`ds` with its odometry mended where it stalled (at the scan times), and the stalls;
    `ds` itself when there is none. `odometry`: the odometry at the scan times; `stretches`:
    its `still_stretches`, each mapped without odometry by `config` and `slam` (None: the
    defaults); `progress(m)`: m more of the stretches' scan pairs matched."""
    if not stretches:
        return ds, []
    # on use, as map_run loads the mapper: GTSAM and scipy.ndimage
    from toolkit.slam.run import slam_trajectory  # noqa: PLC0415

    steps = se2.between(odometry[:-1], odometry[1:])
    found: list[Stall] = []
    for first, last in stretches:
        part = Dataset(t=ds.t[first : last + 1], ranges=ds.ranges[first : last + 1], laser=ds.laser)
        velocity = _lead(steps, first)
        poses = slam_trajectory(part, "gaussian", config, None, slam, progress, velocity)[0].poses
        end = se2.between(poses[:1], poses[-1:])[0]
        moved, turned = float(np.hypot(end[0], end[1])), abs(float(end[2]))
        if moved < MOVED and turned < TURNED:
            continue  # the robot stood still
        steps[first:last] = se2.between(poses[:-1], poses[1:])
        found.append(Stall(first, last, moved, turned))
    if not found:
        return ds, found
    mended = compose_steps(odometry[0], steps)
    return replace(ds, odometry=PoseStream(ds.t, mended)), found


__all__ = ["MIN_STILL", "MOVED", "STILL", "TURNED", "Stall", "mend_stalls", "still_stretches"]
