"""The streaming matcher with a motion model for logs without odometry: constant velocity,
filtered, its forward part weighed by how far the fit observes it (`toolkit.slam.localmap`'s
docstring says why). Its own module so that scan-to-map (`toolkit.slam.scanmap`) and the
keyframe front end (`toolkit.slam.localmap`, which may fit the heading on scan-to-map's grid,
`toolkit.slam.heading`) both build on it without an import cycle."""

from __future__ import annotations

import math
from collections import deque
from typing import TYPE_CHECKING, Any

import numba as nb
import numpy as np

from toolkit import se2
from toolkit.align import scan as sc
from toolkit.dataset import LaserGeometry

if TYPE_CHECKING:  # the heading map builds on scan-to-map, which builds on this module
    from toolkit.slam.heading import HeadingMap

VELOCITY_GAIN = 0.3  # share of a scan's matched motion taken into the velocity (1: the last)
PROBE_SHIFT = 0.05  # m: the prediction moved this far forward and back to see whether the fit
# observes forward motion (0: no probe; the forward velocity filtered like the rest)
PROBE_EVERY = 3  # scans: the probe's response measured on every third scan; the forward
# motions of the scans before it wait for it. Kept from the probe before instead, a response
# went stale where a corridor turned bare between two probes: building world 305's velocity
# took two unobserved fits, 40% fast, at 0.97, ran 14% fast for 15 m and mapped 0.666 m off


GAP_MOST = 10.0  # the prediction carries the velocity over at most this many of the last
# intervals (a capture that lost scans: three tenths lost at random leave gaps of up to
# seven; the simulated corridor so, 2,000 scans, worlds 0-15, mapped 0.64 m off with 3, 0.17
# m with 10)
JITTER = math.log(1.25)  # intervals within 25% of the velocity's are the same interval;
# beyond it (a scan dropped doubles it) the velocity is rescaled to the scan's
# (`MotionMatcher._per_interval`). A log's times are on the scanner's slots (`on_slots`), so
# this tells one period from two; it also holds for times given as they were stamped


PHASE_HALF = 25  # scans each side over which the stamps' phase against the period is
# averaged (`slot_numbers`): the clock's offset, jitter of a third of a period averaged out,
# a host clock that wanders followed
PERIOD_REACH = 0.2  # the period is looked for within this share of the intervals' median
# (`lattice_period`), ...
PERIOD_STEP = 0.001  # ... in steps of this share, ...
PERIOD_BLOCKS = 16  # ... on this many blocks ...
PERIOD_BLOCK = 256  # ... of this many scans spread over the log


def on_slots(t: np.ndarray) -> np.ndarray:
    """The scan times the motion model reads: each scan on its slot of the scanner's period
    (`_clock`), from the first scan's time. A host that stamps
    scans as it reads them spreads a fixed rate: the Mines URG logs' intervals span 0.69-1.39
    of their 98 ms, and beyond `JITTER` each read as a change of speed (exp1, without
    odometry, 1.23 m off its map with odometry); a lost scan leaves its slot empty.
    A single scan, or times whose median interval is not positive, are returned as they are."""
    t = np.asarray(t, np.float64)
    clock = _clock(t)
    if clock is None:
        return t
    period, slots = clock
    times: np.ndarray = t[0] + period * slots
    return times


def slot_numbers(t: np.ndarray, period: float) -> np.ndarray:
    """Each scan's slot of `period` s since the first scan's, later than the scan before's.
    The clock's offset is the stamps' phase against the period, averaged over `PHASE_HALF`
    scans each side (a lost scan leaves the phase as it was); then the slots, one of the
    three nearest each stamp less the offset, most likely as a whole (`_likeliest_slots`):
    the stamps' spread about them against a slot left empty as often as the log leaves
    them. Each stamp rounded alone, a stamp late by more than half a period took the next
    scan's slot and every scan after it moved one on: jittered by a third of a period, the
    simulated corridor and building read 73-93 of 2,000 scans as lost where none was, and
    captures that lost a fifth of their scans 3-7% off in their period; so, 0-3 and 0.15%."""
    lags = (t - t[0]) / period
    phase = np.exp(2j * np.pi * lags)
    sums = np.concatenate([[0], np.cumsum(phase)])
    i = np.arange(len(t))
    around = sums[np.minimum(i + PHASE_HALF + 1, len(t))] - sums[np.maximum(i - PHASE_HALF, 0)]
    offset = np.unwrap(np.angle(around) / (2 * np.pi), period=1.0)
    near = lags - offset
    spread = max(float(np.sqrt(np.mean((near - np.rint(near)) ** 2))), 0.02)
    span = max(float(np.rint(near[-1]) - np.rint(near[0])), 1.0)
    empty = min(max((span - (len(t) - 1)) / span, 1e-3), 0.5)  # share of the slots
    slots: np.ndarray = _likeliest_slots(near, 0.5 / spread**2, -math.log(empty))
    return slots


@nb.njit(cache=True, nogil=True)
def _likeliest_slots(near: np.ndarray, weight: float, skip: float) -> np.ndarray:
    """Viterbi over each scan's three candidate slots (the nearest to `near` and one each
    side, all after the scan before's lowest, so each has a way in): cost `weight` times the
    squared distance to the candidate, plus `skip` per slot left empty; the slots from the
    first's."""
    n = len(near)
    cands = np.zeros((n, 3))
    back = np.zeros((n, 3), np.int8)
    cost = np.zeros(3)
    following = np.zeros(3)
    for k in range(3):
        cands[0, k] = np.rint(near[0]) + k - 1
        cost[k] = weight * (near[0] - cands[0, k]) ** 2
    for i in range(1, n):
        centre = max(np.rint(near[i]), cands[i - 1, 0] + 2.0)
        for k in range(3):
            slot = centre + k - 1
            cands[i, k] = slot
            best, arg = np.inf, 0
            for j in range(3):
                if slot > cands[i - 1, j]:
                    total = cost[j] + skip * (slot - cands[i - 1, j] - 1.0)
                    if total < best:
                        best, arg = total, j
            following[k] = best + weight * (near[i] - slot) ** 2
            back[i, k] = arg
        cost[:] = following
    k = int(np.argmin(cost))
    slots = np.zeros(n)
    for i in range(n - 1, -1, -1):
        slots[i] = cands[i, k]
        k = back[i, k]
    slots -= slots[0]
    return slots


def lattice_period(t: np.ndarray, period: float) -> float:
    """The period within `PERIOD_REACH` of `period` whose lattice the stamps fit best: the
    power of their phases summed over `PERIOD_BLOCKS` blocks of `PERIOD_BLOCK` scans (a block
    short enough that a wandering clock keeps its phase). The intervals' median of a capture
    that lost a fifth of its scans and jitters by a third of a period is up to 7% long."""
    starts = np.unique(np.linspace(0, max(len(t) - PERIOD_BLOCK, 0), PERIOD_BLOCKS).astype(int))
    shares = np.arange(-PERIOD_REACH, PERIOD_REACH + PERIOD_STEP / 2, PERIOD_STEP)
    rates = 1.0 / (period * (1.0 + shares))
    power = np.zeros(len(shares))
    for first in starts:
        since = t[first : first + PERIOD_BLOCK] - t[first]
        power += np.abs(np.exp(2j * np.pi * np.outer(rates, since)).sum(axis=1)) ** 2
    return period * (1.0 + float(shares[np.argmax(power)]))


def scan_clock(t: np.ndarray) -> dict[str, Any]:
    """What `on_slots` reads in a log's times: the scanner's `period` (s), the 5th and 95th
    percentiles of the intervals in periods (`spread`; a host's jitter) and the scans `lost`
    (the empty slots); empty where it leaves the times as they are."""
    t = np.asarray(t, np.float64)
    clock = _clock(t)
    if clock is None:
        return {}
    period, slots = clock
    low, high = np.percentile(np.diff(t) / period, [5, 95])
    lost = int(slots[-1]) - (len(t) - 1)
    return {"period": period, "spread": [round(float(low), 3), round(float(high), 3)], "lost": lost}


def jitters(clock: dict[str, Any]) -> bool:
    """Whether `scan_clock`'s intervals spread beyond `JITTER` (5th or 95th percentile)."""
    return bool(clock) and max(abs(math.log(r)) for r in clock["spread"] if r > 0) > JITTER


def _clock(t: np.ndarray) -> tuple[float, np.ndarray] | None:
    """The scanner's period and each scan's slot of it (`slot_numbers`). The period: the
    median of the intervals within half a period of it (from the median interval, three
    times), the lattice's (`lattice_period`), then twice the slope of the times over their
    slots; None for one scan or a median interval of 0."""
    if len(t) < 2:
        return None
    dt = np.diff(t)
    period = float(np.median(dt))
    if not period > 0:
        return None
    for _ in range(3):
        near = dt[(dt > 0.5 * period) & (dt < 1.5 * period)]
        if len(near) == 0:
            break
        period = float(np.median(near))
    period = lattice_period(t, period)
    for _ in range(2):
        slots = slot_numbers(t, period)
        slope = float(np.polyfit(slots, t, 1)[0])
        if not slope > 0:
            break
        period = slope
    return period, slots


SLIDE_MOST = 0.007  # m: a vehicle's scan whose fit moved it sideways further than this ...
SLIDE_KEEP = 0.5  # ... is fitted again from the prediction's forward motion and the fitted
# turn, and that fit kept where it slides less than this share of the first (`_unslid`).
# Where the fit has one minimum the refit returns to it and is not kept. 0.02 m left the
# simulated building at 100 degrees and 0.5 degrees a beam 0.24 m off (0.11 m at 0.007) and
# missed the slides of a log three times as dense; 0.004 slid one building the other way


RESUME_TURN = 0.1  # rad/s: a velocity turning faster than this is a turn; once it turns
# slower again, its forward part resumes at least the median of ...
RESUME_SCANS = 20  # ... the forward parts of the last this many scans before the turn
# (`MotionMatcher._resume`)


class MotionMatcher(sc.StreamMatcher):
    """`StreamMatcher` whose `push` takes odometry or None; with None, the pose predicted by
    constant velocity plays the odometry's part. The velocity (per scan interval) starts at
    `step` (robot frame; None: standstill, then the first matched motion) and follows the
    matched motion by `gain` of the difference per scan; its forward part (robot x) by `gain`
    times the square of the share of a `probe` m forward offset of the prediction that the
    fit takes out (`response`; probe 0: by `gain`). Probed every `probe_every` scans, the
    forward motions of the scans in between are taken in at the next probe, by its response
    (`_follow_probed`). `probe_filters` False: the response is
    measured, but the forward part follows by `gain` like the rest (the start-velocity
    pass). `heading`: each scan's heading is fitted to this local map of the keyframes
    (`MatchConfig.heading_map`), the keyframe kept with the fitted pose, before the velocity
    takes the motion. `resume`: once a turn ends, the forward part is at least the speed
    before it (`_resume`; a vehicle's, not a swaying hand-held scanner's). `unslide`: a fit
    that moved the robot sideways is fitted again without the slide (`_unslid`; a vehicle's
    too). `interval`: the seconds `step` is per (0: the first scan interval's;
    `_per_interval`). The times given to `push_predicted` are taken as they are; a log's are
    put on the scanner's slots first (`on_slots`, as `toolkit.slam.localmap.sequential`
    does)."""

    def __init__(
        self,
        laser: LaserGeometry,
        config: sc.MatchConfig | None = None,
        step: np.ndarray | None = None,
        gain: float = VELOCITY_GAIN,
        probe: float = PROBE_SHIFT,
        probe_every: int = PROBE_EVERY,
        probe_filters: bool = True,
        heading: HeadingMap | None = None,
        resume: bool = True,
        interval: float = 0.0,
        unslide: bool = True,
    ) -> None:
        super().__init__(laser, config)
        self._last = np.zeros(3)
        self._step = np.zeros(3) if step is None else np.asarray(step, np.float64).reshape(3)
        self._known = step is not None  # a velocity to filter the matched motion into
        self.gain = gain
        self.probe_shift = probe
        self.probe_every = max(1, probe_every)
        self.probe_filters = probe_filters
        self.heading = heading
        self._probed = 0  # scans since the last probe
        self._pending: list[float] = []  # forward motions waiting for the next probe
        self.response = 1.0  # the last scan's: share of the forward offset the fit took out
        self._axis = np.array([1.0, 0.0])  # ... along this axis (robot frame; the heading
        # unless `probe_axis` is "motion")
        self._dt = 0.0
        # s: the interval the velocity is per (0: the next scan's)
        self._unit = interval if step is not None else 0.0
        self._t: float | None = None
        vehicle = self.config.probe_axis == "heading"  # not a swaying hand-held scanner
        self.resume = resume and vehicle  # a vehicle's turns
        self._straight: deque[float] = deque(maxlen=RESUME_SCANS)  # forward parts before
        self._turning = False
        self.unslide = unslide and vehicle  # fits checked for a slide sideways (`_unslid`)

    def _checked(self, scan: np.ndarray, odo: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """A vehicle's fit checked for a slide sideways (`_unslid`) before the scan is kept."""
        return self._unslid(scan, odo, pose) if self.unslide else pose

    def _unslid(self, scan: np.ndarray, odo: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """A vehicle does not move sideways, but a fit seeded without the turn a scan began
        (the velocity's turn lags it) can: in a narrow view the walls ahead let a turn about a
        point metres ahead stand for the turn on the spot (the simulated corridor at 100
        degrees without odometry slid 1.1 m sideways through one corner). A fit that slid
        more than `SLIDE_MOST` is fitted again from the prediction's forward motion, no slide
        and the fitted turn, and that fit kept where it slides less than `SLIDE_KEEP` of it."""
        moved = se2.between(self._last[None], pose[None])[0]
        if abs(moved[1]) <= SLIDE_MOST:
            return pose
        forward = float(se2.between(self._last[None], odo[None])[0, 0])
        seed = se2.compose(self._last[None], np.array([[forward, 0.0, moved[2]]]))[0]
        out_pose, out_cov, out_stats = np.empty(3), np.empty((3, 3)), np.empty(4)
        again = self._match(scan, seed, out_pose, out_cov, out_stats)
        slide = float(se2.between(self._last[None], again[None])[0, 1])
        if abs(slide) >= SLIDE_KEEP * abs(moved[1]):
            return pose
        self.pose[:], self.covariance[:], self.stats[:] = out_pose, out_cov, out_stats
        return again

    def set_velocity(self, step: np.ndarray, interval: float = 0.0) -> None:
        """Go on from the next scan with this motion per scan interval (robot frame), of
        `interval` s (0: the next scan's)."""
        self._step = np.asarray(step, np.float64).reshape(3)
        self._known = True
        self._unit = interval
        self._pending.clear()
        self._straight.clear()
        self._turning = False

    def push_predicted(self, ranges: np.ndarray, t: float | None = None) -> np.ndarray:
        """Take the next scan of a log without odometry (at time `t`, to scale the motion to
        uneven scan intervals); return the robot pose."""
        first = not self._started
        step = self._step
        if t is not None and self._t is not None and self._dt > 0:
            scale = min((t - self._t) / self._dt, GAP_MOST)
            step = step * scale
        predicted = se2.compose(self._last[None], step[None])[0]
        if first:
            predicted = np.zeros(3)
        else:  # the "odometry" is the corrected frame: the keyframe's pose is its own odometry
            self._key_odometry[:] = self._key_pose
        probed = False
        if not first and self._known and self.probe_shift > 0:
            probed = self._probed % self.probe_every == 0
            if probed:
                self.response = self._forward_response(ranges, predicted)
            self._probed += 1
        pose = self.push(ranges, predicted)
        if self.heading is not None:
            if not first:  # the heading fitted to the map; the keyframe keeps the fitted pose
                pose = self.heading.refine(ranges, pose)
                if self.keyed:
                    self._key_pose[:] = pose
            if self.keyed:
                self.heading.add(ranges, pose)
        if not first:
            if t is not None and self._t is not None:
                self._dt = t - self._t
                self._per_interval()
            moved = se2.between(self._last[None], pose[None])[0]
            if self._known and self._filters:
                self._follow_probed(moved, probed)
            elif self._known:
                self._step = self._step + np.full(3, self.gain) * (moved - self._step)
            else:
                self._step, self._known = moved, True
            if self.resume and self._known:
                self._resume()
        self._last = pose
        self._t = t
        return pose

    def _per_interval(self) -> None:
        """Where this scan's interval is not the velocity's (beyond `JITTER`), the velocity
        and the forward motions it holds (waiting for a probe, and before a turn) rescaled to
        it, so that the scan's motion is filtered into a velocity of the same interval. Mixed,
        a log whose intervals vary (scans dropped from a capture, a log recorded as the robot
        moved) took a motion over two intervals into a velocity of one: on the simulated
        corridor without odometry, a tenth of its scans dropped at random, 1.3 m off (0.14 m
        with every scan); intel's corrected log without odometry grew to 4,000 km."""
        if self._unit <= 0:  # the first interval (or none yet: a repeated time)
            self._unit = self._dt
            return
        if self._dt <= 0 or abs(math.log(self._dt / self._unit)) <= JITTER:
            return
        ratio = self._dt / self._unit
        self._unit = self._dt
        self._step = self._step * ratio
        self._pending = [along * ratio for along in self._pending]
        self._straight = deque((speed * ratio for speed in self._straight), RESUME_SCANS)

    def _resume(self) -> None:
        """A turn on the spot takes the velocity's forward part to about zero, and on a bare
        stretch after it the fit observes too little forward motion to find the speed again
        (the simulated building at 2,000 scans lost 3.2 m over the 400 scans after one
        corner): once the velocity turns slower than `RESUME_TURN` again, its forward part is
        at least the median of the `RESUME_SCANS` straight scans' before the turn. Where the
        robot did slow down, the fit takes the rest out as it observes it."""
        per_second = 1.0 / self._dt if self._dt > 0 else 10.0  # no clock: 10 scans a second
        turning = abs(float(self._step[2])) * per_second > RESUME_TURN
        if not turning and not self._turning:
            self._straight.append(float(self._step[0]))
        elif not turning:  # the turn has ended
            if self._straight:
                self._step[0] = max(float(self._step[0]), float(np.median(self._straight)))
            self._straight.clear()
        self._turning = turning

    @property
    def _filters(self) -> bool:
        """Whether the probe's response weighs the forward part of the velocity."""
        return self.probe_filters and self.probe_shift > 0

    def _follow_probed(self, moved: np.ndarray, probed: bool) -> None:
        """The velocity follows the matched motion `moved`: across the probed axis and in turn
        by `gain` at once; along it at the next probe (`probed`: this scan was probed), by
        `gain` times the square of that probe's response, for this scan and the ones that
        waited for it (none when every scan is probed)."""
        u = self._axis
        d = moved - self._step
        d_along = float(d[:2] @ u)
        self._step = self._step + self.gain * np.r_[d[:2] - d_along * u, d[2]]
        self._pending.append(float(moved[:2] @ u))
        if not probed:
            return
        share = self.response**2
        for along in self._pending:
            self._step[:2] += self.gain * share * (along - float(self._step[:2] @ u)) * u
        self._pending.clear()

    def _probe_axis(self) -> np.ndarray:
        """Unit vector (robot frame) to probe along: the heading, or with `probe_axis`
        "motion" the velocity's translation where it moves (1 mm a scan or more)."""
        v = self._step[:2]
        norm = float(np.hypot(v[0], v[1]))
        if self.config.probe_axis == "motion" and norm >= 1e-3:
            return np.asarray(v / norm)
        return np.array([1.0, 0.0])

    def _forward_response(self, ranges: np.ndarray, predicted: np.ndarray) -> float:
        """The share (0..1) of a `probe_shift` forward offset of the prediction that the fit
        takes out: the scan fitted from the prediction moved forward and moved back."""
        d = self.probe_shift
        around = np.broadcast_to(predicted, (2, 3))
        if self.config.probe_axis == "motion":
            u = self._axis = self._probe_axis()
            offsets = np.array([[-d * u[0], -d * u[1], 0.0], [d * u[0], d * u[1], 0.0]])
            fitted = np.array([self.probe(ranges, seed) for seed in se2.compose(around, offsets)])
            back, ahead = se2.between(around, fitted)[:, :2] @ u
        else:
            seeds = se2.compose(around, np.array([[-d, 0.0, 0.0], [d, 0.0, 0.0]]))
            fitted = np.array([self.probe(ranges, seed) for seed in seeds])
            back, ahead = se2.between(around, fitted)[:, 0]
        kept = (ahead - back) / (2 * d)  # 1: the fit kept the offset; 0: took it out
        return float(min(max(1.0 - kept, 0.0), 1.0))
