"""Whether the laser is mounted as the log says: turned round (yaw off by pi) or upside down
(its beams in the opposite order), told from the scans and the odometry.

A laser mounted backwards but logged as facing forward sees the world move towards it while
the odometry drives forward; one mounted upside down in a format without its mounting
(a raw LMS-200 capture, a table, a CARMEN log of a driver that did not flip it) sees every
turn the other way. Every matcher then fights the odometry: on the simulated corridor (2,000
scans) the mapper ends 7.6-8.1 m off with the laser turned round and 32.5 m with its beams
reversed (0.11-0.13 m as mounted).

`mounting` matches pairs of scans about 0.3 m or 0.3 rad apart along the odometry under the
four mountings (as logged, upside down, turned round, both), each seeded by the odometry's
motion as that laser would see it, and counts which fits more of the returns. The yaw is
decided first (as logged or turned round, each with its better beam order), over the pairs
where the two differ by `MARGIN` of the returns; then the beam order under that yaw. A
straight step of a laser mounted upside down is the mirror image of a straight step of one
mounted level, so only turns and sideways motion tell the beam order: the simulator's
mirror-symmetric corridors give few such pairs. A mounting other than the logged one is taken
when at least `MIN_PAIRS` pairs tell and `SHARE` of them agree.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from toolkit import se2
from toolkit.align import scan as sc
from toolkit.dataset import LaserGeometry

MOVE, TURN = 0.3, 0.3  # m, rad: a pair's second scan is the first this far along the odometry
FAR, FAR_TURN = 1.0, 0.8  # m, rad: ... and no further (the scans must still overlap)
HORIZON = 200  # scans looked ahead of a pair's first scan for its second
PAIRS = 1000  # pairs tried at most, evenly spread over the log
MARGIN = 0.1  # share of the returns by which one mounting must fit more to tell
MIN_PAIRS = 8  # fewer pairs that tell: the mounting as logged (the simulated corridor's
# corners give 9-10)
#: The matcher of the vote: held near its seed (no heading ladder, 0.3 m and 0.3 rad at most),
#: so that a seed of the wrong mounting cannot find its way to the right fit (with the
#: mapper's matcher, 3 of the corridor's pairs told and 36 of freiburg-campus's, 0.19 of them
#: wrongly; held, 9 and 214, 0.01)
VOTE = sc.MatchConfig(rescue_step=0.0, max_turn=0.3, max_correction=0.3)
SHARE = 0.7  # share of the telling pairs that must agree on another mounting


@dataclass(frozen=True)
class Vote:
    """Of `pairs` pairs that tell the two apart, the share `share` that fits the other."""

    pairs: int
    share: float

    @property
    def decided(self) -> bool:
        return self.pairs >= MIN_PAIRS and self.share >= SHARE

    def to_dict(self) -> dict[str, float | int]:
        return {"pairs": self.pairs, "share": round(self.share, 3)}


@dataclass(frozen=True)
class Mounting:
    """The laser turned round (`backwards`) and upside down (`upside_down`): their votes."""

    backwards: Vote
    upside_down: Vote

    @property
    def changed(self) -> bool:
        return self.backwards.decided or self.upside_down.decided

    def laser(self, laser: LaserGeometry) -> LaserGeometry:
        """`laser` mounted as the votes decide."""
        return mounted(laser, self.backwards.decided, self.upside_down.decided)

    def describe(self) -> str:
        """What the run says: the laser read as mounted how, on what evidence."""
        votes = (("turned round", self.backwards), ("upside down", self.upside_down))
        return " and ".join(
            f"{how} ({vote.share:.0%} of {vote.pairs} pairs)" for how, vote in votes if vote.decided
        )

    def to_dict(self) -> dict[str, dict[str, float | int]]:
        return {"backwards": self.backwards.to_dict(), "upside_down": self.upside_down.to_dict()}


def mounted(laser: LaserGeometry, backwards: bool, upside_down: bool) -> LaserGeometry:
    """`laser` turned round (its yaw plus pi) and / or upside down (its beam angles mirrored
    in its own frame, as a roll of pi turns them)."""
    if upside_down:
        laser = replace(laser, angle_min=-laser.angle_min, angle_increment=-laser.angle_increment)
    if backwards:
        laser = replace(laser, yaw=float(se2.wrap(laser.yaw + np.pi)))
    return laser


def step_pairs(odometry: np.ndarray, most: int = PAIRS) -> np.ndarray:
    """Up to `most` pairs (i, j), evenly spread: j the first scan MOVE m or TURN rad along the
    odometry from i (looked for over the next HORIZON scans), kept when within FAR m and
    FAR_TURN rad."""
    n = len(odometry)
    if n < 2:
        return np.empty((0, 2), dtype=np.int64)
    starts = np.unique(np.linspace(0, n - 2, min(most, n - 1)).astype(np.int64))
    later = starts[:, None] + 1 + np.arange(HORIZON)  # each start's look-ahead (P x HORIZON)
    inside = later < n
    later = np.minimum(later, n - 1)
    origin = np.broadcast_to(odometry[starts, None], (*later.shape, 3))
    ahead = se2.between(origin.reshape(-1, 3), odometry[later].reshape(-1, 3)).reshape(origin.shape)
    moved = np.hypot(ahead[..., 0], ahead[..., 1])
    far = ((moved >= MOVE) | (np.abs(ahead[..., 2]) >= TURN)) & inside
    k = np.argmax(far, axis=1)  # the first scan far enough along, where any
    rows = np.arange(len(starts))
    kept = far[rows, k] & (moved[rows, k] <= FAR) & (np.abs(ahead[rows, k, 2]) <= FAR_TURN)
    return np.column_stack([starts[kept], later[rows, k][kept]]).astype(np.int64)


def mounting(ranges: np.ndarray, odometry: np.ndarray, laser: LaserGeometry) -> Mounting:
    """The votes on how `laser` is mounted, from the scans `ranges` (S x B) and the odometry
    at the scan times (S x 3)."""
    pairs = step_pairs(odometry, PAIRS)
    if len(pairs) == 0:
        return Mounting(Vote(0, 0.0), Vote(0, 0.0))
    firsts, seconds = ranges[pairs[:, 0]], ranges[pairs[:, 1]]
    steps = se2.between(odometry[pairs[:, 0]], odometry[pairs[:, 1]])
    fits: dict[tuple[bool, bool], np.ndarray] = {}
    for turned in (False, True):
        for over in (False, True):
            geometry = mounted(laser, turned, over)
            seeds = se2.laser_motion(steps, geometry)
            matched = sc.match_scan_pairs(firsts, seconds, seeds, geometry, VOTE)
            fits[turned, over] = matched.agreement
    level = np.maximum(fits[False, False], fits[False, True])
    round_ = np.maximum(fits[True, False], fits[True, True])
    backwards = _vote(level, round_)
    yaw = backwards.decided
    return Mounting(backwards, _vote(fits[yaw, False], fits[yaw, True]))


def _vote(logged: np.ndarray, other: np.ndarray) -> Vote:
    telling = np.abs(other - logged) >= MARGIN
    pairs = int(telling.sum())
    return Vote(pairs, float((other > logged)[telling].mean()) if pairs else 0.0)


__all__ = ["MIN_PAIRS", "SHARE", "Mounting", "Vote", "mounted", "mounting", "step_pairs"]
