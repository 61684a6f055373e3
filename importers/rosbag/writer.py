"""Write a Dataset as a ROS bag with rosbags' writers and serialisers.

Topics: LaserScan on `scan_topic` (frame `frame_id`; NaN written as +inf, "no return" in
REP 117), nav_msgs/Odometry on `odom_topic` (odom -> base_link), ground truth as
nav_msgs/Odometry on `gt_topic` (map -> base_link), and the laser mounting as one static
transform base_link -> frame_id on /tf_static.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from importers.base import host_stamps
from toolkit.atomic import atomic_path
from toolkit.dataset import Dataset, LaserGeometry
from toolkit.errors import ToolkitError

if TYPE_CHECKING:  # Msg exists for type checkers only
    from rosbags.typesys.store import Msg

VERSIONS = ("ros1", "ros2", "mcap")
TFMESSAGE = "tf2_msgs/msg/TFMessage"


def _typestore(ros1: bool) -> Typestore:
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if TFMESSAGE not in store.fielddefs:
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TFMESSAGE))
    return store


class _Messages:
    """Message objects of one typestore, ROS1 or ROS2 header conventions."""

    def __init__(self, store: Typestore, ros1: bool) -> None:
        self.store = store
        self.ros1 = ros1
        self.types = store.types

    def header(self, t: float, frame: str, seq: int = 0) -> Msg:
        sec = math.floor(t)
        nsec = min(round((t - sec) * 1e9), 999_999_999)
        stamp = self.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        if self.ros1:
            return self.types["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame)
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def quaternion(self, yaw: float) -> Msg:
        return self.types["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
        )

    def odometry(self, t: float, x: float, y: float, theta: float, parent: str, seq: int) -> object:
        ty = self.types
        pose = ty["geometry_msgs/msg/Pose"](
            position=ty["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=self.quaternion(theta),
        )
        zero = ty["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        return ty["nav_msgs/msg/Odometry"](
            header=self.header(t, parent, seq),
            child_frame_id="base_link",
            pose=ty["geometry_msgs/msg/PoseWithCovariance"](
                pose=pose, covariance=np.zeros(36, np.float64)
            ),
            twist=ty["geometry_msgs/msg/TwistWithCovariance"](
                twist=ty["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                covariance=np.zeros(36, np.float64),
            ),
        )

    def mounting(
        self, t: float, frame: str, laser: LaserGeometry, upside_down: bool = False
    ) -> Msg:
        """base_link -> `frame`: the laser's position and heading; `upside_down`, also turned
        over about its x axis (a roll of 180 deg: its z axis points down)."""
        ty = self.types
        rotation = self.quaternion(laser.yaw)
        if upside_down:  # Rz(yaw) Rx(pi)
            rotation = ty["geometry_msgs/msg/Quaternion"](
                x=math.cos(laser.yaw / 2), y=math.sin(laser.yaw / 2), z=0.0, w=0.0
            )
        transform = ty["geometry_msgs/msg/TransformStamped"](
            header=self.header(t, "base_link"),
            child_frame_id=frame,
            transform=ty["geometry_msgs/msg/Transform"](
                translation=ty["geometry_msgs/msg/Vector3"](x=laser.x, y=laser.y, z=laser.z),
                rotation=rotation,
            ),
        )
        return ty[TFMESSAGE](transforms=[transform])

    def serialize(self, msg: object, msgtype: str) -> bytes | memoryview:
        if self.ros1:
            return self.store.serialize_ros1(msg, msgtype)
        return self.store.serialize_cdr(msg, msgtype)


def write_bag(
    ds: Dataset,
    out: Path,
    version: str = "ros1",
    scan_topic: str = "/scan",
    odom_topic: str = "/odom",
    gt_topic: str = "/ground_truth",
    frame_id: str = "laser",
    name: str = "log",
    upside_down: bool = False,
    clock_jitter: float = 0.0,
    seed: int = 0,
) -> Path:
    """Write the bag under directory `out`, atomically; returns its path. `upside_down`: the
    laser as one mounted turned over records it (`_Messages.mounting`; each scan's beams in
    the opposite order, from the mirrored last angle), which the reader turns back.
    `clock_jitter`: the spread (sd, s) of the scans' stamps (header and bag time) around their
    times, kept in order, as a host that stamps each scan when it reads it (drawn from `seed`);
    the odometry and the ground truth keep theirs."""
    if version not in VERSIONS:
        raise ToolkitError(f"rosbag version {version!r}: expected one of {', '.join(VERSIONS)}")
    if not clock_jitter >= 0:
        raise ToolkitError(f"rosbag writer: clock_jitter must be >= 0, not {clock_jitter}")
    ros1 = version == "ros1"
    final = out / (f"{name}.bag" if ros1 else name)
    with atomic_path(final) as path:
        msgs = _Messages(_typestore(ros1), ros1)
        stamps = host_stamps(ds.t, clock_jitter, np.random.default_rng(seed))
        streams = _streams(
            ds, msgs, stamps, scan_topic, odom_topic, gt_topic, frame_id, upside_down
        )
        if ros1:
            with Writer1(path) as w1:
                conns1 = {
                    topic: w1.add_connection(topic, msgtype, typestore=msgs.store)
                    for topic, msgtype in streams.types.items()
                }
                for topic, stamp, raw in streams.ordered():
                    w1.write(conns1[topic], stamp, raw)
        else:
            plugin = StoragePlugin.MCAP if version == "mcap" else StoragePlugin.SQLITE3
            with Writer2(path, version=9, storage_plugin=plugin) as w2:
                conns2 = {
                    topic: w2.add_connection(topic, msgtype, typestore=msgs.store)
                    for topic, msgtype in streams.types.items()
                }
                for topic, stamp, raw in streams.ordered():
                    w2.write(conns2[topic], stamp, raw)
    return final


class _Streams:
    def __init__(self) -> None:
        self.types: dict[str, str] = {}
        self.items: list[tuple[int, str, bytes | memoryview]] = []

    def add(self, topic: str, msgtype: str, t: float, raw: bytes | memoryview) -> None:
        self.types.setdefault(topic, msgtype)
        self.items.append((round(t * 1e9), topic, raw))

    def ordered(self) -> list[tuple[str, int, bytes | memoryview]]:
        order = sorted(range(len(self.items)), key=lambda i: self.items[i][0])
        return [(self.items[i][1], self.items[i][0], self.items[i][2]) for i in order]


def _streams(
    ds: Dataset,
    msgs: _Messages,
    stamps: np.ndarray,
    scan_topic: str,
    odom_topic: str,
    gt_topic: str,
    frame: str,
    upside_down: bool = False,
) -> _Streams:
    """The bag's messages, the scans stamped `stamps`."""
    ty = msgs.types
    streams = _Streams()
    laser = ds.laser
    ranges = np.where(np.isnan(ds.ranges), np.float32(np.inf), ds.ranges).astype(np.float32)
    angle_min = laser.angle_min
    if upside_down:  # turned over, beam k points at -angle(B - 1 - k) in the laser's frame
        ranges = np.ascontiguousarray(ranges[:, ::-1])
        angle_min = -(laser.angle_min + laser.angle_increment * (laser.beams - 1))
    dt = float(np.median(np.diff(ds.t))) if ds.n_scans > 1 else 0.0
    empty = np.zeros(0, np.float32)
    if ds.n_scans:
        first = float(min(ds.t[0], stamps[0]))
        streams.add(
            "/tf_static",
            TFMESSAGE,
            first,
            msgs.serialize(msgs.mounting(first, frame, laser, upside_down), TFMESSAGE),
        )
    for i, t in enumerate(stamps.tolist()):
        msg = ty["sensor_msgs/msg/LaserScan"](
            header=msgs.header(t, frame, i),
            angle_min=angle_min,
            angle_max=angle_min + laser.angle_increment * (laser.beams - 1),
            angle_increment=laser.angle_increment,
            time_increment=0.0,
            scan_time=dt,
            range_min=laser.range_min,
            range_max=laser.range_max,
            ranges=ranges[i],
            intensities=empty,
        )
        streams.add(
            scan_topic,
            "sensor_msgs/msg/LaserScan",
            t,
            msgs.serialize(msg, "sensor_msgs/msg/LaserScan"),
        )
    for topic, frame_poses, parent in (
        (odom_topic, ds.odometry, "odom"),
        (gt_topic, ds.groundtruth, "map"),
    ):
        if frame_poses is None:
            continue
        for i, row in enumerate(_rows(frame_poses)):
            odo = msgs.odometry(*row, parent=parent, seq=i)
            streams.add(
                topic, "nav_msgs/msg/Odometry", row[0], msgs.serialize(odo, "nav_msgs/msg/Odometry")
            )
    return streams


def _rows(frame: pd.DataFrame) -> list[tuple[float, float, float, float]]:
    values = frame.loc[:, ["t", "x", "y", "theta"]].to_numpy(np.float64)
    return [(float(a), float(b), float(c), float(d)) for a, b, c, d in values]
