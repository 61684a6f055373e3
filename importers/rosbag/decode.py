"""Decode sensor_msgs/LaserScan messages from their raw bytes, a whole batch at once.

ROS1 and little-endian CDR (ROS2) share the layout up to the frame_id string:

    ROS1: seq u32 | sec u32 | nsec u32 | len u32 | frame_id[len]
    CDR:  encapsulation (4) | sec i32 | nsec u32 | len u32 (with NUL) | frame_id[len] | pad to 4
    then: 7 float32 (angle_min, angle_max, angle_increment, time_increment, scan_time,
          range_min, range_max) | n u32 | float32[n] ranges | m u32 | float32[m] intensities

so `sec` is at byte 4, `nsec` at 8 and the string length at 12 in both. When every message of
a batch has the same length, frame_id and beam count (the usual case), the fields are strided
views of one (S x N) byte array: no Python work per message. Otherwise each message is parsed
on its own with `struct` (still no rosbags object per message), which also finds the message
where the beam count changes. `decode_with_typestore` is the rosbags route, kept for
comparison (bench) and for big-endian CDR.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

PARAMS = (
    "angle_min",
    "angle_max",
    "angle_increment",
    "time_increment",
    "scan_time",
    "range_min",
    "range_max",
)
_FIXED = 16  # bytes before the frame_id characters
_AFTER = 36  # 7 float32 + n + m


class BeamCountChanged(Exception):
    """Message `index` (within the batch) has `beams` ranges, the earlier ones `expected`."""

    def __init__(self, index: int, beams: int, expected: int) -> None:
        super().__init__(index, beams, expected)
        self.index, self.beams, self.expected = index, beams, expected


@dataclass
class ScanBatch:
    """Decoded LaserScans: stamps, the 7 scalar fields, ranges; `ok` marks readable messages."""

    sec: np.ndarray  # int64 (S,)
    nsec: np.ndarray  # int64 (S,)
    params: np.ndarray  # float64 (S, 7), columns as PARAMS
    ranges: np.ndarray  # float32 (S, B)
    ok: np.ndarray  # bool (S,): False = malformed message, its row is undefined
    frame_id: str = ""


def _u32_column(buf: np.ndarray, offset: int) -> np.ndarray:
    return np.ascontiguousarray(buf[:, offset : offset + 4]).view("<u4")[:, 0]


def _f32_block(buf: np.ndarray, offset: int, count: int) -> np.ndarray:
    return np.array(buf[:, offset : offset + 4 * count], order="C").view("<f4")  # a copy


def decode_scans(raws: Sequence[bytes | memoryview], cdr: bool, beams: int | None) -> ScanBatch:
    """Decode a batch; `beams` is the beam count seen so far (None for the first batch).

    Raises BeamCountChanged for a well-formed message with another beam count.
    """
    if not raws:
        return _empty(beams or 0)
    lengths = np.fromiter(map(len, raws), dtype=np.int64, count=len(raws))
    if lengths.min() == lengths.max() and lengths[0] >= _FIXED + _AFTER:
        fast = _decode_uniform(raws, int(lengths[0]), cdr, beams)
        if fast is not None:
            return fast
    return _decode_each(raws, cdr, beams)


def _decode_uniform(
    raws: Sequence[bytes | memoryview], size: int, cdr: bool, beams: int | None
) -> ScanBatch | None:
    """The strided fast path, or None when the batch is not uniform."""
    buf = np.frombuffer(b"".join(raws), dtype=np.uint8).reshape(len(raws), size)
    if cdr and not (buf[:, 1] == 1).all():
        return None  # big-endian CDR somewhere
    strlen = _u32_column(buf, 12)
    if strlen.min() != strlen.max():
        return None
    length = int(strlen[0])
    p = _FIXED + ((length + 3) // 4 * 4 if cdr else length)
    if p + _AFTER > size:
        return None
    n = _u32_column(buf, p + 28)
    if n.min() != n.max():
        return None
    count = int(n[0])
    end = p + 32 + 4 * count
    if end + 4 > size:
        return None
    m = _u32_column(buf, end)
    if m.min() != m.max() or end + 4 + 4 * int(m[0]) != size:
        return None
    if beams is not None and count != beams:
        raise BeamCountChanged(0, count, beams)
    frame = bytes(buf[0, _FIXED : _FIXED + length]).rstrip(b"\0").decode("utf-8", "replace")
    return ScanBatch(
        sec=_u32_column(buf, 4).astype(np.int64),
        nsec=_u32_column(buf, 8).astype(np.int64),
        params=_f32_block(buf, p, 7).astype(np.float64),
        ranges=_f32_block(buf, p + 32, count),
        ok=np.ones(len(raws), dtype=bool),
        frame_id=frame,
    )


_Parsed = tuple[int, int, tuple[float, ...], int, int, str, str]


def _parse_one(raw: bytes | memoryview, cdr: bool) -> _Parsed:
    """(sec, nsec, params, beams, offset of ranges, byte order, frame_id) of one message.

    ValueError if the message is malformed.
    """
    endian = ">" if cdr and len(raw) > 1 and raw[1] == 0 else "<"
    size = len(raw)
    if size < _FIXED + _AFTER:
        raise ValueError("too short")
    sec, nsec, length = struct.unpack_from(endian + "III", raw, 4)
    p = _FIXED + ((length + 3) // 4 * 4 if cdr else length)
    if p + _AFTER > size:
        raise ValueError("frame_id longer than the message")
    *params, count = struct.unpack_from(endian + "7fI", raw, p)
    end = p + 32 + 4 * count
    if end + 4 > size:
        raise ValueError("ranges longer than the message")
    (m,) = struct.unpack_from(endian + "I", raw, end)
    if end + 4 + 4 * m != size:
        raise ValueError("intensities do not fill the message")
    frame = bytes(raw[_FIXED : _FIXED + length]).rstrip(b"\0").decode("utf-8", "replace")
    return sec, nsec, tuple(params), count, p + 32, endian, frame


def _decode_each(raws: Sequence[bytes | memoryview], cdr: bool, beams: int | None) -> ScanBatch:
    parsed: list[_Parsed | None] = []
    for i, raw in enumerate(raws):
        try:
            one = _parse_one(raw, cdr)
        except (ValueError, struct.error):
            parsed.append(None)
            continue
        if beams is None:
            beams = one[3]
        elif one[3] != beams:
            raise BeamCountChanged(i, one[3], beams)
        parsed.append(one)
    out = _empty(beams or 0, len(raws))
    frame = ""
    for i, (raw, fields) in enumerate(zip(raws, parsed, strict=True)):
        if fields is None:
            continue
        sec, nsec, params, count, offset, endian, frame = fields
        out.sec[i], out.nsec[i] = sec, nsec
        out.params[i] = params
        out.ranges[i] = np.frombuffer(raw, dtype=endian + "f4", count=count, offset=offset)
        out.ok[i] = True
    out.frame_id = frame
    return out


def _empty(beams: int, rows: int = 0) -> ScanBatch:
    return ScanBatch(
        sec=np.zeros(rows, np.int64),
        nsec=np.zeros(rows, np.int64),
        params=np.zeros((rows, len(PARAMS)), np.float64),
        ranges=np.zeros((rows, beams), np.float32),
        ok=np.zeros(rows, dtype=bool),
    )


def decode_with_typestore(
    raws: Sequence[bytes | memoryview],
    deserialize: Callable[[bytes | memoryview], Any],
    beams: int | None,
) -> ScanBatch:
    """The same result through rosbags' deserialiser, one message object at a time."""
    msgs: list[Any] = []
    for i, raw in enumerate(raws):
        try:
            msg = deserialize(raw)
        except Exception:  # rosbags raises many types on damaged bytes; the row is dropped
            msgs.append(None)
            continue
        count = len(msg.ranges)
        if beams is None:
            beams = count
        elif count != beams:
            raise BeamCountChanged(i, count, beams)
        msgs.append(msg)
    out = _empty(beams or 0, len(raws))
    for i, msg in enumerate(msgs):
        if msg is None:
            continue
        out.sec[i], out.nsec[i] = msg.header.stamp.sec, msg.header.stamp.nanosec
        out.params[i] = [getattr(msg, name) for name in PARAMS]
        out.ranges[i] = msg.ranges
        out.ok[i] = True
        out.frame_id = msg.header.frame_id
    return out
