"""`rosbag`: sensor_msgs/LaserScan and odometry (nav_msgs/Odometry or tf) from ROS bags.

Reads ROS1 `.bag` (v2.0 through rosbags, or the recovery reader when rosbags rejects the file,
and the pre-2010 `#ROSRECORD V1.2`), ROS2 sqlite3 and mcap bags. Decisions recorded in
meta.json (`rosbag` and the import report's notes):

- time: header.stamp; a zero stamp falls back to the message's bag time.
- ranges: readings outside [range_min, range_max) of their message, 0, inf or NaN become NaN;
  the count is kept (`rosbag.invalid_readings`).
- geometry: angle_min / angle_increment of the first message (a change of beam count is an
  error naming the message); mounting from a base_link (or base_footprint) -> laser-frame
  transform on /tf_static or /tf, else zero: its position and the heading of the laser's x
  axis; a laser mounted upside down (the transform turns its z axis down, as a roll of 180
  deg does) has its beam angles mirrored (angle_min and angle_increment negated), and a scan
  plane tilted by more than 10 deg is noted.
- odometry: the one nav_msgs/Odometry topic (ground-truth topics aside), or odom -> base_link
  (base_footprint) transforms on /tf; ground truth from an Odometry topic named like
  /ground_truth (`-O gt_topic=`).

The writer produces what this reader reads: LaserScan on /scan, Odometry on /odom, ground
truth as nav_msgs/Odometry on /ground_truth and the mounting as a static tf.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
import pandas as pd
from rich.progress import TaskID

from importers import register
from importers.base import FormatOptions, Importer, option
from importers.rosbag.decode import PARAMS, BeamCountChanged, decode_scans, decode_with_typestore
from importers.rosbag.source import (
    BagSource,
    Topic,
    bag_kind,
    describe,
    open_bag,
    open_recovery,
)
from importers.rosbag.writer import write_bag
from toolkit.dataset import Dataset, ImportReport, LaserGeometry, make_meta
from toolkit.errors import FormatError, ToolkitError
from toolkit.progress import task

LASERSCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
GT_NAMES = ("ground_truth", "groundtruth", "base_pose_ground_truth", "gt")
BASE_FRAMES = ("base_link", "base_footprint")
BATCH = 4096


def _bare(name: str) -> str:
    return name.strip("/")


LEVEL = math.cos(math.radians(10.0))  # a scan plane tilted more than 10 deg is noted


class _Quaternion(Protocol):
    x: float
    y: float
    z: float
    w: float


def _yaw(q: _Quaternion) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _listing(topics: Sequence[Topic]) -> str:
    return ", ".join(f"{t.name} ({t.count} msgs)" for t in topics)


def _pick(
    wanted: str | None, candidates: list[Topic], kind: str, flag: str, bag: Path
) -> Topic | None:
    """The topic the user named, or the only candidate; a one-line error when unclear."""
    if wanted is not None:
        for topic in candidates:
            if _bare(topic.name) == _bare(wanted):
                return topic
        known = _listing(candidates) or "none"
        raise ToolkitError(
            f"no {kind} topic {wanted!r} in the bag; {kind} topics: {known}", file=bag
        )
    if len(candidates) > 1:
        raise ToolkitError(
            f"{len(candidates)} {kind} topics: {_listing(candidates)}; choose one with {flag}",
            file=bag,
        )
    return candidates[0] if candidates else None


@dataclass
class _Collected:
    scans: list[Any] = field(default_factory=list)  # decoded ScanBatch per batch
    scan_times: list[int] = field(default_factory=list)  # bag time ns
    odom: list[tuple[int, Any]] = field(default_factory=list)
    gt: list[tuple[int, Any]] = field(default_factory=list)
    tf: list[tuple[int, Any]] = field(default_factory=list)


@dataclass(frozen=True)
class RosbagOptions(FormatOptions):
    """Reading a ROS bag."""

    scan_topic: str | None = option(
        None, "the sensor_msgs/LaserScan topic", shown="the only one, else name it"
    )
    odom_topic: str | None = option(
        None, "the nav_msgs/Odometry topic (or a tf frame)", shown="the only one, else tf"
    )
    gt_topic: str | None = option(
        None, "nav_msgs/Odometry topic with ground truth", shown="one named ground_truth"
    )
    odom_frame: str = option("odom", "tf parent frame of the odometry")
    base_frame: str | None = option(
        None, "tf child frame of the odometry", shown="base_link or base_footprint"
    )
    decode: Literal["raw", "rosbags"] = option(
        "raw", "raw: LaserScan bytes decoded in bulk; rosbags: per message"
    )


@dataclass(frozen=True)
class RosbagWriteOptions(FormatOptions):
    """Writing a ROS bag."""

    version: Literal["ros1", "ros2", "mcap"] = option(
        "ros1", "ros1 (NAME.bag), ros2 (sqlite3, NAME/) or mcap (NAME/)"
    )
    scan_topic: str = option("/scan", "LaserScan topic")
    odom_topic: str = option("/odom", "Odometry topic")
    gt_topic: str = option("/ground_truth", "ground-truth Odometry topic")
    frame_id: str = option("laser", "the scans' frame")
    name: str = option("log", "bag name")
    upside_down: bool = option(
        False, "the laser mounted upside down (the tf turns it over; the scans as it sees them)"
    )
    clock_jitter: float = option(0.0, "s: spread (sd) of the scans' stamps around their times")
    seed: int = option(0, "seed of the clock's jitter")


@register
class RosbagImporter(Importer[RosbagOptions, RosbagWriteOptions]):
    name = "rosbag"
    summary = "ROS1 .bag (v2.0, pre-2010 V1.2), ROS2 sqlite3/mcap: LaserScan, Odometry or tf"
    Options = RosbagOptions
    WriteOptions = RosbagWriteOptions

    def sniff(self, path: Path) -> bool:
        return bag_kind(path) is not None

    def read(self, sources: Sequence[Path], options: RosbagOptions) -> Dataset:
        paths = [Path(s) for s in sources]
        with open_bag(paths) as bag:
            try:
                return _read(bag, options)
            except ToolkitError:
                raise
            except Exception as e:  # rosbags failing mid-way through a damaged bag
                if bag.reader != "rosbags" or bag.cdr or len(paths) > 1:
                    raise FormatError(
                        f"cannot read the bag ({describe(e)})", file=paths[0]
                    ) from None
                why = f"rosbags: {describe(e)}"
        with open_recovery(paths[0], bag.typestore, why) as again:
            return _read(again, options)

    def write(
        self, ds: Dataset, out: Path, options: RosbagWriteOptions | None = None
    ) -> list[Path]:
        """Write `ds` as a bag under directory `out`: version ros1 (log.bag), ros2 or mcap (log/)."""
        o = options or RosbagWriteOptions()
        return [
            write_bag(
                ds, Path(out), version=o.version, scan_topic=o.scan_topic,
                odom_topic=o.odom_topic, gt_topic=o.gt_topic, frame_id=o.frame_id, name=o.name,
                upside_down=o.upside_down, clock_jitter=o.clock_jitter, seed=o.seed,
            )
        ]  # fmt: skip


def _read(bag: BagSource, options: RosbagOptions) -> Dataset:
    where = bag.paths[0]
    topics = list(bag.topics.values())
    lasers = [t for t in topics if t.msgtype == LASERSCAN]
    if not lasers and options.scan_topic is None:
        listed = ", ".join(f"{t.name} [{t.msgtype}]" for t in topics) or "none"
        raise FormatError(f"no sensor_msgs/LaserScan topic; topics: {listed}", file=where)
    scan = _pick(options.scan_topic, lasers, "LaserScan", "--scan-topic", where)
    assert scan is not None
    odoms = [t for t in topics if t.msgtype == ODOMETRY]
    gt_wanted = options.gt_topic
    gts = [t for t in odoms if _bare(t.name).split("/")[-1] in GT_NAMES]
    gt = _pick(gt_wanted, odoms if gt_wanted else gts[:1], "ground-truth", "-O gt_topic=", where)
    tfs = [t for t in topics if t.msgtype in TF_TYPES]
    tf_names = {t.name for t in tfs}
    odom: Topic | None = None
    odom_from_tf = False
    if options.odom_topic is not None and _bare(options.odom_topic) in {_bare(n) for n in tf_names}:
        odom_from_tf = True
    else:
        plain = [t for t in odoms if gt is None or t.name != gt.name]
        if options.odom_topic is None and not plain and tfs:
            odom_from_tf = True
        else:
            odom = _pick(options.odom_topic, plain, "Odometry", "--odom-topic", where)

    report = ImportReport()
    for note in bag.notes:
        report.note(note)
    if bag.skipped:
        report.drop("damaged bag record", bag.skipped, where=str(where))
    got = _collect(bag, options, scan, odom, gt, tf_names)
    return _assemble(bag, options, scan, odom, gt, odom_from_tf, got, report)


def _collect(
    bag: BagSource,
    options: RosbagOptions,
    scan: Topic,
    odom: Topic | None,
    gt: Topic | None,
    tf_names: set[str],
) -> _Collected:
    """One pass over the bag: LaserScans decoded in batches, the rest deserialised."""
    use_rosbags = options.decode == "rosbags"
    got = _Collected()
    pending: list[bytes | memoryview] = []
    beams: int | None = None
    done = 0

    def flush() -> None:
        nonlocal beams, done
        if not pending:
            return
        try:
            if use_rosbags:
                batch = decode_with_typestore(
                    pending, lambda raw: bag.deserialize(raw, LASERSCAN), beams
                )
            else:
                batch = decode_scans(pending, bag.cdr, beams)
        except BeamCountChanged as e:
            index = done + e.index
            stamp = got.scan_times[index] / 1e9
            raise FormatError(
                f"beam count changes from {e.expected} to {e.beams} at message {index} "
                f"(bag time {stamp:.3f}); import the parts separately",
                file=bag.paths[0],
                record=f"{scan.name} message {index}",
            ) from None
        if batch.ok.any():
            beams = batch.ranges.shape[1]
        got.scans.append(batch)
        done += len(pending)
        pending.clear()

    others = {t.name: t for t in (odom, gt) if t is not None}
    wanted = [scan.name, *others, *tf_names]
    with task("reading bag", scan.count) as (progress, bar):
        for topic, stamp, raw in bag.messages(wanted):
            if topic == scan.name:
                pending.append(raw)
                got.scan_times.append(stamp)
                if len(pending) >= BATCH:
                    flush()
                    progress.advance(TaskID(bar), BATCH)
                continue
            msgtype = bag.topics[topic].msgtype
            try:
                msg = bag.deserialize(raw, msgtype)
            except Exception:  # a damaged pose message is dropped and counted, not fatal
                got.tf.append((stamp, None)) if topic in tf_names else None
                continue
            if topic in tf_names:
                got.tf.append((stamp, msg))
            elif gt is not None and topic == gt.name:
                got.gt.append((stamp, msg))
            else:
                got.odom.append((stamp, msg))
        flush()
    return got


def _stamped_poses(items: list[tuple[int, Any]]) -> tuple[pd.DataFrame, int]:
    """DataFrame (t, x, y, theta) of Odometry messages; and how many stamps were zero."""
    rows = []
    zero = 0
    for bag_time, msg in items:
        stamp = msg.header.stamp
        t = stamp.sec + stamp.nanosec * 1e-9
        if t == 0:
            zero += 1
            t = bag_time / 1e9
        pose = msg.pose.pose
        rows.append((t, pose.position.x, pose.position.y, _yaw(pose.orientation)))
    return _pose_frame(rows), zero


def _pose_frame(rows: list[tuple[float, float, float, float]]) -> pd.DataFrame:
    frame = pd.DataFrame(rows, columns=["t", "x", "y", "theta"], dtype=np.float64)
    frame = frame[np.isfinite(frame.to_numpy()).all(axis=1)]
    return frame.sort_values("t", kind="stable").reset_index(drop=True)


def _tf_odometry(
    items: list[tuple[int, Any]], odom_frame: str, base_frame: str | None
) -> tuple[pd.DataFrame, str | None]:
    rows = []
    child: str | None = base_frame
    for bag_time, msg in items:
        if msg is None:
            continue
        for tr in msg.transforms:
            if _bare(tr.header.frame_id) != odom_frame:
                continue
            name = _bare(tr.child_frame_id)
            if child is None and name in BASE_FRAMES:
                child = name
            if name != child:
                continue
            t = tr.header.stamp.sec + tr.header.stamp.nanosec * 1e-9 or bag_time / 1e9
            rows.append(
                (
                    t,
                    tr.transform.translation.x,
                    tr.transform.translation.y,
                    _yaw(tr.transform.rotation),
                )
            )
    return _pose_frame(rows), child


def _up(q: _Quaternion) -> float:
    """The z component of the laser's z axis in the robot's frame: 1 level, -1 upside down."""
    return 1.0 - 2.0 * (q.x * q.x + q.y * q.y)


def _mounting(
    items: list[tuple[int, Any]], laser_frame: str
) -> tuple[dict[str, float], float] | None:
    """The base_link -> laser transform: x, y, z, yaw (the heading of the laser's x axis)
    and `_up` of its rotation."""
    for _, msg in items:
        if msg is None:
            continue
        for tr in msg.transforms:
            if _bare(tr.header.frame_id) in BASE_FRAMES and _bare(tr.child_frame_id) == laser_frame:
                v, q = tr.transform.translation, tr.transform.rotation
                return {"x": v.x, "y": v.y, "z": v.z, "yaw": _yaw(q)}, _up(q)
    return None


def _assemble(
    bag: BagSource,
    options: RosbagOptions,
    scan: Topic,
    odom: Topic | None,
    gt: Topic | None,
    odom_from_tf: bool,
    got: _Collected,
    report: ImportReport,
) -> Dataset:
    where = bag.paths[0]
    report.records_read = len(got.scan_times)
    if not got.scans:
        raise FormatError(f"no message on LaserScan topic {scan.name}", file=where)
    ok = np.concatenate([b.ok for b in got.scans])
    bag_time = np.asarray(got.scan_times, dtype=np.int64)
    if not ok.any():
        raise FormatError(f"no readable LaserScan message on {scan.name}", file=where)
    if not ok.all():
        first_bad = int(np.flatnonzero(~ok)[0])
        report.drop(
            "malformed LaserScan message",
            int((~ok).sum()),
            where=f"{scan.name} message {first_bad}",
        )
    beams = next(b.ranges.shape[1] for b in got.scans if b.ok.any())
    keep = [b for b in got.scans if b.ok.any()]
    sec = np.concatenate([b.sec[b.ok] for b in keep])
    nsec = np.concatenate([b.nsec[b.ok] for b in keep])
    params = np.concatenate([b.params[b.ok] for b in keep])
    parts = [b.ranges if b.ok.all() else b.ranges[b.ok] for b in keep]
    ranges = np.concatenate(parts) if len(parts) > 1 else parts[0]
    del parts
    frame_id = next((b.frame_id for b in keep if b.frame_id), "")
    bag_time = bag_time[ok]
    del got.scans

    t = sec.astype(np.float64) + nsec.astype(np.float64) * 1e-9
    zero = t == 0
    time_source = "header.stamp"
    if zero.all():
        t = bag_time / 1e9
        time_source = "bag time"
        report.note("LaserScan header stamps are all zero; bag receive times used")
    elif zero.any():
        t[zero] = bag_time[zero] / 1e9
        report.note(f"{int(zero.sum())} LaserScan header stamps are zero; bag time used for those")
    order = np.argsort(t, kind="stable")
    if (np.diff(t) < 0).any():
        report.note("LaserScan stamps are not in order; scans sorted by stamp")
        t, ranges, params, bag_time = t[order], ranges[order], params[order], bag_time[order]

    angle_min, angle_increment = float(params[0, 0]), float(params[0, 2])
    if not (math.isfinite(angle_min) and math.isfinite(angle_increment)):
        raise FormatError(
            "angle_min or angle_increment is not finite",
            file=where,
            record=f"{scan.name} message 0",
        )
    if np.ptp(params[:, 0]) > 1e-6 or np.ptp(params[:, 2]) > 1e-9:
        report.note("angle_min / angle_increment vary between messages; the first message's used")
    rmin = params[:, PARAMS.index("range_min")].astype(np.float32)
    rmax = params[:, PARAMS.index("range_max")].astype(np.float32)
    invalid = ~np.isfinite(ranges)
    invalid |= ranges == 0
    with np.errstate(invalid="ignore"):
        invalid |= ranges < rmin[:, None]
        invalid |= ranges >= rmax[:, None]
    n_invalid = int(invalid.sum())
    ranges[invalid] = np.nan
    del invalid
    if n_invalid:
        report.note(f"{n_invalid} readings outside [range_min, range_max), 0 or inf set to NaN")
    finite_max = rmax[np.isfinite(rmax)]
    finite_min = rmin[np.isfinite(rmin)]
    range_max = (
        float(finite_max.max())
        if finite_max.size
        else float(np.nan_to_num(np.nanmax(ranges, initial=0.0)))
    )
    range_min = max(0.0, float(finite_min.min())) if finite_min.size else 0.0

    laser_frame = _bare(frame_id)
    level: tuple[dict[str, float], float] = ({"x": 0.0, "y": 0.0, "z": 0.0, "yaw": 0.0}, 1.0)
    found = _mounting(got.tf, laser_frame)
    mount, up = found or level
    if found is None:
        which = laser_frame or "laser"
        report.note(f"no base_link -> {which} transform in the bag; laser mounting taken as zero")
    elif not all(math.isfinite(v) for v in (*mount.values(), up)):
        mount, up = level
        report.note("laser mounting transform is not finite; taken as zero")
    if up < 0.0:
        # seen from below, the scan turns the other way: a beam at angle a in the laser's
        # frame points at yaw - a in the robot's
        angle_min, angle_increment = -angle_min, -angle_increment
        report.note(
            "the laser is mounted upside down (its z axis points down): beam angles mirrored"
        )
    if abs(up) < LEVEL:
        tilt = math.degrees(math.acos(min(abs(up), 1.0)))
        report.note(f"the laser's scan plane is tilted {tilt:.0f} deg; its returns taken as level")
    laser = LaserGeometry(beams, angle_min, angle_increment, range_max, range_min, **mount)

    odometry: pd.DataFrame | None = None
    odom_source = "none"
    if odom is not None:
        odometry, zero_odom = _stamped_poses(got.odom)
        odom_source = odom.name
        if zero_odom:
            report.note(f"{zero_odom} Odometry header stamps are zero; bag time used for those")
        report.drop("damaged Odometry message", odom.count - len(got.odom), where=odom.name)
    elif odom_from_tf:
        odom_frame = _bare(options.odom_frame or "odom")
        base = options.base_frame
        odometry, child = _tf_odometry(got.tf, odom_frame, _bare(base) if base else None)
        if odometry.empty:
            odometry = None
            report.note(f"no {odom_frame} -> base_link/base_footprint transform on tf: no odometry")
        else:
            odom_source = f"tf {odom_frame} -> {child}"
    else:
        report.note("no nav_msgs/Odometry topic and no tf: no odometry")
    groundtruth = None
    if gt is not None:
        groundtruth, _ = _stamped_poses(got.gt)
        report.drop("damaged ground-truth message", gt.count - len(got.gt), where=gt.name)
    report.records_kept = len(t)
    meta = make_meta(
        "rosbag",
        bag.paths if all(p.is_file() for p in bag.paths) else _files(bag.paths),
        laser,
        report,
        time_source=time_source,
        rosbag={
            "reader": bag.reader,
            "encoding": "cdr" if bag.cdr else "ros1",
            "scan_topic": scan.name,
            "frame_id": frame_id,
            "odometry": odom_source,
            "groundtruth": gt.name if gt is not None else None,
            "bag_time": [float(bag_time[0]) / 1e9, float(bag_time[-1]) / 1e9],
            "invalid_readings": n_invalid,
            "scan_time": _finite(float(np.median(params[:, PARAMS.index("scan_time")]))),
            "time_increment": _finite(float(np.median(params[:, PARAMS.index("time_increment")]))),
        },
    )
    return Dataset(t, ranges, laser, odometry=odometry, groundtruth=groundtruth, meta=meta)


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _files(paths: Sequence[Path]) -> list[Path]:
    out: list[Path] = []
    for p in paths:
        out.extend(sorted(f for f in p.rglob("*") if f.is_file()) if p.is_dir() else [p])
    return out
