"""The sequential part of the mapper, with a motion model: odometry when the log has it,
constant velocity when it has none.

With odometry every scan pair is independent given its seed, so the batch matcher matches all
pairs at once (`toolkit.poses.build`). Without, each scan's seed is the previous motion
carried on (constant velocity, as KISS-ICP predicts), so scans are matched one after another
through the streaming matcher (`MotionMatcher`, a `StreamMatcher` whose odometry may be
missing): a log without odometry is no longer matched "from standstill".

Along a corridor the matcher sees almost nothing along the axis: it keeps what it is given
(its seed, the prediction) give or take the noise of its few along-axis constraints, and each
scan's motion becomes the next prediction. So the velocity random-walks (the simulated
corridor lost 4-6 m over its first 20 m) and a robot that starts, or leaves a turn on the spot,
at speed is held at standstill ("not moved" matches as well as the truth). These measures,
without odometry only:

- the velocity is filtered: each matched motion moves it by `VELOCITY_GAIN` of the difference
  (an alpha filter; noise of a few cm per scan no longer becomes the velocity);
- the start velocity is not zero: a first pass over the first `START_SCANS` scans (unfiltered,
  so it picks up speed where the walls allow) gives the median motion of its second half, and
  the log is matched from scan 0 with that velocity. Its forward part is the median weighted
  by the square of each scan's forward `response` (below): an unfiltered pass random-walks
  along a featureless stretch, and once at "not moved" it stays there (corridor seed 53 parked over
  scans 90-270 of its pass: plain median 0.002 m a scan against the truth's 0.080, and the
  log lost 11.7 m before doors came into view); the scans whose fit observes forward motion
  give their motion whatever the prediction was. A pass whose second half has no scan that
  observes the forward motion goes on until one does (`START_STRONG`, up to `START_MAX`
  scans: corridor world 192 was bare for its first 28 m, its pass random-walked to rest and
  the log mapped 21 m off);
- the velocity's forward part is filtered only as far as the fit observes it (solution
  remapping, after Zhang, Kaess & Singh 2016, "On degeneracy of optimization-based state
  estimation problems", with the degeneracy measured by the fit's own response): each scan is
  also fitted from the prediction moved `PROBE_SHIFT` forward and back. Where the walls hold
  nothing along the axis the two fits end as far apart as they started (the fit keeps its
  seed: seeded with 0.7 of the truth's motion it returns 0.7 of it, while its covariance
  claims 3 mm; corridor seed 9), and the forward motion it reports is the prediction plus a
  centimetre of noise, which the filter would otherwise random-walk into the velocity. The
  forward gain is `VELOCITY_GAIN` times the square of the share of the offset the fit takes
  out (the `response`; 1: both fits meet, 0: they keep their offset): a scan's forward motion
  is the prediction's but for that share, so as a measurement of the velocity its spread
  grows as 1 / response and its weight (a Kalman gain, against a velocity held steady) as the
  square. With the share itself (until session 20) the velocity sagged 5-10% over the
  partly observed stretches (response 0.05-0.2) and the corridor lost 0.5-1 m there. The
  eigenvalue test (`degenerate_ratio`) does not see any of this: the noise of the walls'
  sampled normals gives the fit its false information;
- after a turn on the spot the forward part resumes at least the speed before it
  (`MotionMatcher._resume`): the turn takes it to about zero, and a bare stretch after it held
  it there for some 300 scans (the building at 2,000 scans lost 3.2 m after one corner);
- a fit that moved the robot sideways is fitted again without the slide
  (`MotionMatcher._unslid`): where the robot turns on the spot, the velocity's turn lags its
  own, and in a narrow view (the LMS-200's 100-degree modes) the fit from a seed without the
  turn took a turn about a point ahead for it (the simulated corridor slid 1.1 m sideways
  through one corner; the velocity learnt the slide).

Measured on the simulator's corridor and building without odometry (docs/maps.md)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from toolkit import se2
from toolkit.align import scan as sc
from toolkit.dataset import Dataset, PoseStream
from toolkit.poses import Method, TrajectoryResult, build, odometry_poses
from toolkit.slam.heading import HeadingMap
from toolkit.slam.motion import PROBE_SHIFT, MotionMatcher, on_slots

STREAM_STEP = 256  # scans the streaming matcher runs between two progress calls
START_SCANS = 300  # scans of the first pass that gives the start velocity
START_SEEN = 1.0  # the first pass's summed squared forward response below which its forward
# speed is the plain median (no scan observed forward motion: nothing to weigh by)
START_MAX = 1500  # scans: the first pass goes on, `START_SCANS` at a time, up to this many ...
START_STRONG = 0.5  # ... until its second half holds `START_SEEN` of squared forward response
# from scans that observe at least this share of it (0: the first `START_SCANS` only)
REST_CHANGE = 0.1  # m: a beam whose range moved this much since the first scan (or whose
# return came or went) has seen motion ...
REST_SHARE = 0.02  # ... and a scan with more such beams than this share is not at rest


def standing(ranges: np.ndarray, chunk: int = 1024) -> int:
    """How many scans the log starts with at rest: scans that differ from the first one by
    the range noise only (at most `REST_SHARE` of the beams moved `REST_CHANGE` or more).
    Along a corridor the matcher cannot tell rest from motion; the scans can."""
    first = ranges[0]
    for start in range(0, len(ranges), chunk):
        block = ranges[start : start + chunk]
        with np.errstate(invalid="ignore"):
            moved = np.abs(block - first) >= REST_CHANGE
        moved |= np.isnan(block) != np.isnan(first)
        going = np.nonzero(moved.mean(axis=1) > REST_SHARE)[0]
        if len(going):
            return start + int(going[0])
    return len(ranges)


def start_velocity(
    ds: Dataset,
    config: sc.MatchConfig | None = None,
    scans: int = START_SCANS,
    begin: int = 0,
    times: np.ndarray | None = None,
) -> np.ndarray | None:
    """The motion per scan (robot frame) to start a log without odometry with: the median
    motion over the second half of a first, unfiltered pass over `scans` scans from scan
    `begin`, its forward part weighted by the square of each scan's forward response (the
    share of a probe offset the fit takes out: 0 where the walls hold nothing along the axis
    and the matched motion is the prediction's); None when there are fewer than 8 scans.
    A pass whose second half never observes the forward motion (a corridor bare for its
    first `scans` scans: its steps have random-walked to any speed, often to rest) goes on,
    `scans` more at a time, up to `START_MAX`, until it does. `times`: the log's times on
    the scanner's slots (None: `on_slots` of them)."""
    total = ds.n_scans - begin
    m = min(scans, total)
    if m < 8:
        return None
    longest = max(m, min(START_MAX, total)) if START_STRONG > 0 else m
    times = on_slots(ds.t) if times is None else times
    first = MotionMatcher(
        ds.laser,
        config,
        gain=1.0,
        probe=PROBE_SHIFT,
        probe_every=1,
        probe_filters=False,
        resume=False,
        unslide=False,
    )
    poses = np.empty((longest, 3))
    seen = np.zeros(longest)  # scan i's forward response (measured from the pass's third scan)
    for i in range(longest):
        poses[i] = first.push_predicted(ds.ranges[begin + i], float(times[begin + i]))
        seen[i] = first.response if i >= 2 else 0.0
        if i + 1 == m:  # the pass's end: its second half's squared responses (responses
            # are 0..1; a partly observed scan's motion is partly the prediction)
            weights = seen[m // 2 + 1 : m] ** 2
            if m == longest or weights[weights >= START_STRONG**2].sum() >= START_SEEN:
                break
            m = min(m + scans, longest)
    steps = se2.between(poses[: m - 1], poses[1:m])[m // 2 :]
    velocity = np.asarray(np.median(steps, axis=0))
    if PROBE_SHIFT > 0 and weights.sum() >= START_SEEN:
        velocity[0] = weighted_median(steps[:, 0], weights)
    return velocity


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The value at which the weights (>= 0, not all 0) sorted by value reach half their sum."""
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def sequential(
    ds: Dataset,
    config: sc.MatchConfig | None = None,
    progress: Callable[[int], object] | None = None,
    velocity: np.ndarray | None = None,
) -> TrajectoryResult:
    """The sequential trajectory of `ds`: the batch matcher seeded by odometry, or the streaming
    matcher seeded by constant velocity (filtered, from `start_velocity`, or from `velocity`,
    the motion per scan the log is known to start with) when the log has no odometry.
    `progress(m)`: m more scan pairs matched (S - 1 in all)."""
    if odometry_poses(ds) is not None:
        return build(ds, "gaussian", config, progress=progress)
    config = config or sc.MatchConfig()
    t0 = time.perf_counter()
    times = on_slots(ds.t)  # the motion model reads the times on the scanner's slots
    if velocity is None:
        rest = standing(ds.ranges)  # the start velocity from where the robot starts moving
        rest = rest if rest > 1 else 0  # the first scan alone is no rest
        velocity = start_velocity(ds, config, begin=rest, times=times)
    else:
        rest = 0
    heading = HeadingMap(ds.laser, config.heading_map) if config.heading_map > 0 else None
    # the velocity is a median of scan steps: per the log's usual interval, which the first
    # one after it need not be (a scan lost there)
    interval = float(np.median(np.diff(times))) if ds.n_scans > 1 else 0.0
    matcher = MotionMatcher(
        ds.laser, config, None if rest else velocity, heading=heading, interval=interval
    )
    poses = np.zeros((ds.n_scans, 3))
    matches = sc.PairMatches.empty(max(ds.n_scans - 1, 0))
    for k in range(ds.n_scans):
        if k == rest and k > 0 and velocity is not None:
            matcher.set_velocity(velocity, interval)
        poses[k] = matcher.push_predicted(ds.ranges[k], float(times[k]))
        if k > 0:  # the pair just matched: its pose, covariance and diagnostics
            sigma, n_used, degenerate, agreement = matcher.stats
            matches.pose[k - 1] = matcher.pose
            matches.covariance[k - 1] = matcher.covariance
            matches.sigma[k - 1], matches.used[k - 1] = sigma, n_used
            matches.degenerate[k - 1], matches.agreement[k - 1] = degenerate, agreement
            if progress is not None and (k % STREAM_STEP == 0 or k == ds.n_scans - 1):
                progress(k % STREAM_STEP or STREAM_STEP)
    seconds = time.perf_counter() - t0
    used = config.to_dict()
    return TrajectoryResult(PoseStream(ds.t, poses), Method.GAUSSIAN, matches, seconds, used)


__all__ = ["MotionMatcher", "sequential", "standing", "start_velocity", "weighted_median"]
