"""A recovery reader for ROS1 bags that rosbags refuses: it walks the records, not the index.

Both on-disk generations share the record framing
`header_len u32 | header (field_len u32 + b"name=value")* | data_len u32 | data`:

- `#ROSBAG V2.0`: op 0x03 bag header, 0x05 chunk (compression none/bz2/lz4) holding
  0x07 connection and 0x02 message data records, 0x04 index data, 0x06 chunk info.
  Index records are skipped (some writers got their lengths wrong: the CCNY demo bag says
  5560 bytes for 278 12-byte entries), so a bad index costs nothing.
- `#ROSRECORD V1.2` (before 2010): op 0x01 message definition, 0x02 message data with
  `topic`, `md5`, `type`, `sec`, `nsec` fields in its header, 0x03 file header, 0x04 index.

A truncated file yields the messages before the damage; `notes` says where it stopped.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from toolkit.errors import FormatError

try:  # optional: only lz4-compressed chunks need it
    import lz4.frame  # type: ignore[import-untyped,unused-ignore]
except ImportError:
    lz4 = None

V2_MAGIC = b"#ROSBAG V2.0\n"
V12_MAGIC = b"#ROSRECORD V1.2\n"
_MAX_HEADER = 1 << 20


@dataclass
class RawTopic:
    msgtype: str  # as written in the bag, e.g. sensor_msgs/LaserScan
    msgdef: str
    count: int = 0


@dataclass
class RawBag:
    """Every message of a bag, in file order: (topic, time in ns, raw bytes)."""

    path: Path
    version: str
    topics: dict[str, RawTopic] = field(default_factory=dict)
    messages: list[tuple[str, int, memoryview]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    skipped: int = 0  # records that could not be read


class _Truncated(Exception):
    pass


def _records(buf: memoryview, pos: int, end: int) -> Iterator[tuple[dict[str, bytes], memoryview]]:
    """Records of buf[pos:end]; raises _Truncated(pos) where a record runs past `end`."""
    while pos < end:
        header, data, nxt = _record_at(buf, pos, end)
        pos = nxt
        yield header, data


def _record_at(buf: memoryview, pos: int, end: int) -> tuple[dict[str, bytes], memoryview, int]:
    if pos + 4 > end:
        raise _Truncated(pos)
    (hlen,) = struct.unpack_from("<I", buf, pos)
    if hlen > _MAX_HEADER or pos + 8 + hlen > end:
        raise _Truncated(pos)
    header = _fields(buf[pos + 4 : pos + 4 + hlen])
    if header is None:
        raise _Truncated(pos)
    (dlen,) = struct.unpack_from("<I", buf, pos + 4 + hlen)
    start = pos + 8 + hlen
    if header.get("op") == b"\x04" and len(header.get("count", b"")) == 4:
        # index data: trust the entry count, not the length (ver 1 = 12 bytes per entry)
        (count,) = struct.unpack_from("<I", header["count"])
        dlen = 12 * count if header.get("ver", b"\x01\x00\x00\x00")[:1] == b"\x01" else dlen
    if start + dlen > end:
        raise _Truncated(pos)
    return header, buf[start : start + dlen], start + dlen


def _fields(raw: memoryview) -> dict[str, bytes] | None:
    out: dict[str, bytes] = {}
    q = 0
    while q < len(raw):
        if q + 4 > len(raw):
            return None
        (flen,) = struct.unpack_from("<I", raw, q)
        q += 4
        if q + flen > len(raw):
            return None
        name, sep, value = bytes(raw[q : q + flen]).partition(b"=")
        if not sep:
            return None
        out[name.decode("latin-1")] = value
        q += flen
    return out if "op" in out else None


def _time(value: bytes) -> int:
    sec, nsec = struct.unpack("<II", value)
    return sec * 1_000_000_000 + nsec


def _conn_fields(data: memoryview) -> dict[str, bytes]:
    parsed = _fields(memoryview(bytes(data) + b"\x04\x00\x00\x00op=\x07"))
    return parsed or {}


def read_bag(path: Path) -> RawBag:
    """Read every message of a ROS1 bag (either generation) without its index."""
    data = path.read_bytes()
    buf = memoryview(data)
    if data.startswith(V2_MAGIC):
        bag = RawBag(path, "2.0")
        _read_v2(bag, buf, len(V2_MAGIC))
    elif data.startswith(V12_MAGIC):
        bag = RawBag(path, "1.2")
        _read_v12(bag, buf, len(V12_MAGIC))
    else:
        raise FormatError("not a ROS1 bag (no #ROSBAG V2.0 or #ROSRECORD V1.2 magic)", file=path)
    return bag


def _read_v2(bag: RawBag, buf: memoryview, pos: int) -> None:
    conns: dict[bytes, str] = {}
    end = len(buf)
    while pos < end:
        try:
            header, data, nxt = _record_at(buf, pos, end)
        except _Truncated:
            resync = _next_chunk(buf, pos + 1)
            if resync is None:
                bag.notes.append(f"stopped at byte {pos}: damaged or truncated record")
                return
            bag.notes.append(f"skipped bytes {pos}..{resync}: damaged record")
            bag.skipped += 1
            pos = resync
            continue
        pos = nxt
        op = header["op"]
        if op == b"\x07":
            _add_connection(bag, conns, header, data)
        elif op == b"\x05":
            try:
                chunk = _decompress(bag.path, header, data)
            except (OSError, ValueError, EOFError, RuntimeError):
                bag.notes.append(f"chunk at byte {pos - len(data)} does not decompress; skipped")
                bag.skipped += 1
                continue
            _read_chunk(bag, conns, memoryview(chunk))


def _read_chunk(bag: RawBag, conns: dict[bytes, str], chunk: memoryview) -> None:
    try:
        for header, data in _records(chunk, 0, len(chunk)):
            op = header["op"]
            if op == b"\x07":
                _add_connection(bag, conns, header, data)
            elif op == b"\x02":
                topic = conns.get(header.get("conn", b""))
                stamp = header.get("time", b"")
                if topic is None or len(stamp) != 8:
                    bag.skipped += 1
                    continue
                bag.messages.append((topic, _time(stamp), data))
                bag.topics[topic].count += 1
    except _Truncated as e:
        bag.notes.append(f"chunk cut short at its byte {e.args[0]}; rest of the chunk skipped")
        bag.skipped += 1


def _add_connection(
    bag: RawBag, conns: dict[bytes, str], header: dict[str, bytes], data: memoryview
) -> None:
    topic = header.get("topic", b"").decode("utf-8", "replace")
    info = _conn_fields(data)
    msgtype = info.get("type", b"").decode("utf-8", "replace")
    if not topic or not msgtype:
        bag.skipped += 1
        return
    conns[header.get("conn", b"")] = topic
    if topic not in bag.topics:
        msgdef = info.get("message_definition", b"").decode("utf-8", "replace")
        bag.topics[topic] = RawTopic(msgtype, msgdef)


def _decompress(path: Path, header: dict[str, bytes], data: memoryview) -> bytes:
    kind = header.get("compression", b"none")
    if kind == b"none":
        return bytes(data)
    if kind == b"bz2":
        return bz2.decompress(data)
    if kind == b"lz4":
        if lz4 is None:
            raise FormatError(
                "lz4-compressed chunks need the lz4 package (pip install lz4)", file=path
            )
        return bytes(lz4.frame.decompress(data))
    raise ValueError(f"compression {kind!r}")


def _next_chunk(buf: memoryview, start: int) -> int | None:
    """Position of the next record that parses as a chunk header, after `start`."""
    raw = buf.obj if isinstance(buf.obj, bytes) else bytes(buf)
    at = start
    while (hit := raw.find(b"op=\x05", at)) >= 0:
        for pos in range(max(start, hit - 64), hit):
            try:
                header, _, _ = _record_at(buf, pos, len(buf))
            except (_Truncated, struct.error):
                continue
            if header.get("op") == b"\x05":
                return pos
        at = hit + 1
    return None


def _read_v12(bag: RawBag, buf: memoryview, pos: int) -> None:
    end = len(buf)
    try:
        for header, data in _records(buf, pos, end):
            op = header["op"]
            if op not in (b"\x01", b"\x02"):
                continue
            topic = header.get("topic", b"").decode("utf-8", "replace")
            msgtype = header.get("type", b"").decode("utf-8", "replace")
            if not topic or not msgtype:
                bag.skipped += 1
                continue
            if topic not in bag.topics:
                msgdef = header.get("def", b"").decode("utf-8", "replace")
                bag.topics[topic] = RawTopic(msgtype, msgdef)
            if op == b"\x02":
                sec, nsec = header.get("sec", b""), header.get("nsec", b"")
                if len(sec) != 4 or len(nsec) != 4:
                    bag.skipped += 1
                    continue
                bag.messages.append((topic, _time(sec + nsec), data))
                bag.topics[topic].count += 1
    except _Truncated as e:
        bag.notes.append(f"stopped at byte {e.args[0]}: damaged or truncated record")
