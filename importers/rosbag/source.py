"""One view of a bag for the importer, whichever reader opened it.

`open_bag` tries rosbags (AnyReader, with a default typestore for bags without message
definitions) and, for a single ROS1 file it rejects, the recovery reader of `ros1raw`.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import ExitStack, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from importers.base import head_bytes
from importers.rosbag import ros1raw
from toolkit.errors import FormatError, ToolkitError

ROS1_MAGICS = (ros1raw.V2_MAGIC[:-1], b"#ROSRECORD")
MCAP_MAGIC = b"\x89MCAP"
SQLITE_MAGIC = b"SQLite format 3\x00"


def normalize_type(msgtype: str) -> str:
    """sensor_msgs/LaserScan -> sensor_msgs/msg/LaserScan (ROS2 spelling, as rosbags uses)."""
    parts = msgtype.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return msgtype


@dataclass
class Topic:
    name: str
    msgtype: str  # normalized
    count: int


@dataclass
class BagSource:
    """Topics, raw messages and a deserialiser; `cdr` tells ROS2 (CDR) from ROS1 bytes."""

    paths: list[Path]
    cdr: bool
    reader: str  # "rosbags" or "recovery (...)"
    topics: dict[str, Topic]
    typestore: Any
    notes: list[str] = field(default_factory=list)
    skipped: int = 0
    _stack: ExitStack | None = None
    _any: Any = None
    _raw: ros1raw.RawBag | None = None

    def messages(self, topics: Sequence[str]) -> Iterator[tuple[str, int, bytes | memoryview]]:
        """(topic, bag time ns, raw bytes) of the given topics, in bag order."""
        wanted = set(topics)
        if self._raw is not None:
            for topic, stamp, raw in self._raw.messages:
                if topic in wanted:
                    yield topic, stamp, raw
            return
        conns = [c for c in self._any.connections if c.topic in wanted]
        if not conns:
            return
        for conn, stamp, raw in self._any.messages(connections=conns):
            yield conn.topic, stamp, raw

    def deserialize(self, raw: bytes | memoryview, msgtype: str) -> object:
        if self.cdr:
            return self.typestore.deserialize_cdr(raw, msgtype)
        return self.typestore.deserialize_ros1(raw, msgtype)

    def close(self) -> None:
        if self._stack is not None:
            self._stack.close()

    def __enter__(self) -> BagSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def describe(error: BaseException) -> str:
    """An exception as one short line: type and message, newlines folded."""
    text = " ".join(str(error).split())
    text = text if len(text) <= 200 else text[:197] + "..."
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def bag_kind(path: Path) -> str | None:
    """'ros1', 'ros2' or None, from the magic bytes or a rosbag2 directory's metadata.yaml."""
    if path.is_dir():
        meta = path / "metadata.yaml"
        return (
            "ros2"
            if meta.is_file() and b"rosbag2_bagfile_information" in head_bytes(meta)
            else None
        )
    head = head_bytes(path, 16)
    if head.startswith(ROS1_MAGICS):
        return "ros1"
    if head.startswith(MCAP_MAGIC) or (head.startswith(SQLITE_MAGIC) and path.suffix == ".db3"):
        return "ros2"
    return None


def open_bag(paths: Sequence[Path]) -> BagSource:
    """Open one ROS2 bag (directory, .db3 or .mcap) or one or more ROS1 .bag files."""
    kinds = {p: bag_kind(p) for p in paths}
    for p, kind in kinds.items():
        if kind is None:
            raise FormatError(
                "not a ROS bag (no ROS1 magic, rosbag2 metadata, .db3 or .mcap)", file=p
            )
    if len(set(kinds.values())) > 1 or (len(paths) > 1 and "ros2" in kinds.values()):
        raise ToolkitError("give one ROS2 bag, or any number of ROS1 bags, not a mix")
    ros2 = next(iter(kinds.values())) == "ros2"
    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    first = paths[0]
    legacy = not ros2 and head_bytes(first, 16).startswith(b"#ROSRECORD")
    error = "pre-2010 #ROSRECORD format" if legacy else None
    if not legacy and (ros2 or all(p.suffix == ".bag" for p in paths)):
        try:
            return _open_rosbags(list(paths), ros2, store)
        except ToolkitError:
            raise
        except Exception as e:  # rosbags raises many types on damaged or odd bags
            error = f"rosbags: {describe(e)}"
            if ros2 or len(paths) > 1:
                raise FormatError(f"cannot read the bag ({error})", file=first) from None
    if len(paths) > 1:
        raise ToolkitError("ROS1 bags not named *.bag can be imported one at a time", file=first)
    return open_recovery(first, store, error)


def _open_rosbags(paths: list[Path], ros2: bool, store: Typestore) -> BagSource:
    stack = ExitStack()
    try:
        reader = stack.enter_context(AnyReader(paths, default_typestore=store))
        topics = {
            name: Topic(name, normalize_type(info.msgtype or ""), info.msgcount)
            for name, info in reader.topics.items()
        }
    except BaseException:
        stack.close()
        raise
    return BagSource(
        list(paths), ros2, "rosbags", topics, reader.typestore, _stack=stack, _any=reader
    )


def open_recovery(path: Path, store: Typestore, why: str | None) -> BagSource:
    raw = ros1raw.read_bag(path)
    topics: dict[str, Topic] = {}
    types: dict[str, Any] = {}
    for name, info in raw.topics.items():
        msgtype = normalize_type(info.msgtype)
        topics[name] = Topic(name, msgtype, info.count)
        if msgtype not in store.fielddefs and info.msgdef:
            try:
                types.update(get_types_from_msg(info.msgdef, msgtype))
            except Exception:  # an unparsable definition only matters if that topic is used
                continue
    if types:
        with suppress(Exception):  # a clash with a known type: the known one is kept
            store.register(types)
    reason = f" ({why})" if why else ""
    notes = [
        f"read with the recovery reader for ROS1 v{raw.version}{reason}: records walked "
        "directly, the bag's index was ignored",
        *raw.notes,
    ]
    return BagSource(
        [path],
        False,
        f"recovery (ROS1 v{raw.version})",
        topics,
        store,
        notes,
        raw.skipped,
        _raw=raw,
    )
