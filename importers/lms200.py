"""SICK LMS-2xx raw serial captures (`lms200`): the byte stream the scanner sent.

Telegrams (``STX 0x02 | ADDR | LEN u16 | CMD | DATA | STATUS | CRC u16``, little-endian, see
FORMATS.md) are found by a vectorized search over the whole buffer: every ``0x02`` followed by
address 0x80/0x81, a reply command (high bit set) and a plausible LEN (2..806) is a candidate.
The CRC of all candidates is computed at once: in numpy, byte position by byte position
across frames, or compiled with numba (``-O crc=numba``). bench_import_lms200 compares the
two: numba's kernel is about 1.7x faster, but importing numba costs 1-2 s, so numba is the
default only for captures of 1 GB or more, or when numba is loaded already. Valid
telegrams are accepted greedily in stream order, a valid telegram consuming its bytes, so
line noise, ACK/NAK bytes and damaged frames are skipped and the search resynchronises on
the next intact telegram. Every skipped byte and rejected frame is counted in the import report.

Measured-values replies (0xB0) become scans: 13-bit values in the units of the count word
(cm or mm); the special codes 0x1FF7..0x1FFF (invalid, dazzling, overflow, low S/N, channel
error, above maximum) become NaN. A capture of partial scans only (interlaced mode) has them
assembled, P consecutive partials with indices 0..P-1 into one scan at 0.25° (see
`assemble`); partial scans among full ones are counted and dropped. Scans whose variant
(value count, units) differs from the capture's most common one are dropped too. Geometry
follows the variant: 181/361 values -> 180° from -90°, 101/201/401 values -> 100° from -50°
(0° = the scanner's right, counter-clockwise).

Time: a capture has no clock. In order of preference:

1. a side file of byte-offset timestamps, ``<capture>.times`` (or ``<capture stem>.times``, or
   given as a second source, or ``-O times=FILE``): text, one ``OFFSET T`` pair per line
   (``#`` comments allowed), OFFSET the byte offset in the capture where a telegram's STX
   was received, T its time in seconds; offsets increasing. A telegram's time is the linear
   interpolation (and extrapolation beyond the ends) of its STX offset. A serial logger that
   timestamps each read() writes exactly this; so does this module's writer, one pair per
   measured-values telegram, damaged or not.
2. ``--rate R`` (scans per second): a telegram's time is its slot / R, the slot being its STX
   offset divided by the median spacing of consecutive scans, rounded (gaps left by damaged
   frames stay gaps).
3. otherwise the baud rate (``-O baud=``, default 38400): STX offset x 10 bits / baud (8N1
   framing, a saturated line), from the capture's first byte.

``meta["time_source"]`` says which; ``meta["capture"]`` holds the byte and telegram counts.
"""

from __future__ import annotations

import importlib
import io
import json
import lzma
import sys
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Literal

import numpy as np
import pandas as pd
from rich.progress import TaskID

from importers import register
from importers.base import (
    FormatOptions,
    Importer,
    head_bytes,
    host_stamps,
    open_binary,
    open_text,
    option,
)
from toolkit.atomic import atomic_file
from toolkit.dataset import Dataset, ImportReport, LaserGeometry, make_meta
from toolkit.errors import FormatError, ToolkitError
from toolkit.progress import task

STX, ACK, NAK = 0x02, 0x06, 0x15
MAX_TELEGRAM = 812
MAX_LEN = MAX_TELEGRAM - 6  # LEN counts CMD + DATA + STATUS
MIN_LEN = 2  # a reply has at least CMD and STATUS
MEASURED = 0xB0
SPECIAL_MIN = 0x1FF7  # 0x1FF7..0x1FFF are error / no-return codes, never a range
VALUE_MASK = 0x1FFF
UNITS = {0: ("cm", 0.01), 1: ("mm", 0.001)}
RANGE_MAX = {"cm": 81.91, "mm": 8.191}
#: value count -> (first angle, step) in degrees, laser frame (0° ahead, CCW)
VARIANTS = {181: (-90.0, 1.0), 361: (-90.0, 0.5), 101: (-50.0, 1.0), 201: (-50.0, 0.5), 401: (-50.0, 0.25)}  # fmt: skip
REPLY_NAMES = {0xA0: "mode change", 0xBB: "variant", 0x92: "command rejected", 0x90: "power-on"}
PARTIAL_STEP = 0.25  # degrees between the partial scans of interlaced mode
CAPTURE_SUFFIXES = (".lms", ".bin", ".raw")
TIMES_SUFFIX = ".times"
TRUTH_SUFFIX = ".truth.json"
DEFAULT_BAUD = 38400
BITS_PER_BYTE = 10  # 8N1
CHUNK = 8192  # frames decoded per block: bounded index arrays
CRC_BLOCK = 8192  # frames per CRC block
SEARCH_FRAMES = 2 * CRC_BLOCK  # candidate frames CRC-checked per progress step (~12 MB)
NUMBA_MIN_BYTES = 1 << 30  # from here the numba CRC repays its import (bench_import_lms200)


# ---------------------------------------------------------------- CRC


def crc16_sick(data: bytes | bytearray | np.ndarray) -> int:
    """SICK's telegram CRC of one byte string (reference, sequential)."""
    crc = prev = 0
    for b in bytes(data):
        crc = (((crc & 0x7FFF) << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1) & 0xFFFF
        crc ^= b | (prev << 8)
        prev = b
    return crc


def crc_frames_numpy(buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """CRC of buf[s : s + n] for every (s, n), vectorized across frames.

    The CRC is sequential within a frame, so the loop runs over byte positions (at most 810)
    and each step updates a block of frames at once. Blocks of CRC_BLOCK frames that are
    neighbours in the stream keep the bytes being read in cache (measured: 2-3x faster
    than all frames in one block on a 50 MB capture), and reading them transposed another
    2x (a contiguous row per step instead of a gather).
    """
    out = np.empty(len(starts), np.uint32)
    for a in range(0, len(starts), CRC_BLOCK):
        out[a : a + CRC_BLOCK] = _crc_block(
            buf, starts[a : a + CRC_BLOCK], lengths[a : a + CRC_BLOCK]
        )
    return out


def _crc_block(buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """One block. Frames sorted by length, longest first, so the active ones are a prefix; their
    bytes transposed (one row per byte position) so each step reads a contiguous row; uint16
    arithmetic, so the shift wraps by itself."""
    count = len(starts)
    if count == 0:
        return np.zeros(0, np.uint32)
    order = np.argsort(-np.asarray(lengths), kind="stable")
    first = np.asarray(starts, np.int64)[order]
    longest_first = np.asarray(lengths, np.int64)[order]
    width = int(longest_first[0])
    rows = np.zeros((count, width), np.uint8)
    fits = first <= buf.size - width
    rows[fits] = np.lib.stride_tricks.sliding_window_view(buf, width)[first[fits]]
    for i in np.flatnonzero(~fits).tolist():  # the few near the end of the buffer
        tail = buf[first[i] : first[i] + width]
        rows[i, : tail.size] = tail
    columns = np.ascontiguousarray(rows.T)
    del rows
    steps = np.arange(width)
    active = (count - np.searchsorted(longest_first[::-1], steps, side="right")).tolist()
    crc = np.zeros(count, np.uint16)
    prev = np.zeros(count, np.uint16)
    high = np.empty(count, np.uint16)
    for k, m in enumerate(active):  # m: frames longer than k
        c, p, h, b = crc[:m], prev[:m], high[:m], columns[k, :m]
        np.right_shift(c, 15, out=h)
        h *= 0x8005
        c <<= 1
        c ^= h
        p <<= 8
        c ^= p
        c ^= b
        p[:] = b
    out = np.empty(count, np.uint32)
    out[order] = crc
    return out


def crc_frames_numba(buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Same as `crc_frames_numpy`, compiled with numba (sequential per frame)."""
    kernel = _numba_crc().crc_kernel
    return np.asarray(kernel(buf, np.asarray(starts, np.int64), np.asarray(lengths, np.int64)))


def _numba_crc() -> ModuleType:
    """The numba kernel's module, loaded on first use: importing numba costs 1-2 s."""
    return importlib.import_module("importers._lms200_crc")


CRC_METHODS = {"numpy": crc_frames_numpy, "numba": crc_frames_numba}


def default_crc_method(size: int = 0) -> str:
    """numba for captures of NUMBA_MIN_BYTES or more, or when numba is loaded anyway; else numpy.

    Measured (bench_import_lms200): the numba kernel is about 1.7x faster than the numpy one,
    but importing numba costs 1-2 s per process, which only pays off on big captures.
    """
    if size < NUMBA_MIN_BYTES and "numba" not in sys.modules:
        return "numpy"
    try:
        _numba_crc()
    except Exception:  # numba missing or broken: the numpy path needs nothing more
        return "numpy"
    return "numba"


# ---------------------------------------------------------------- telegram search


class Telegrams:
    """The telegrams of a capture: accepted (CRC-valid, non-overlapping) and rejected."""

    def __init__(
        self, buf: np.ndarray, crc: str = "numpy", progress: Callable[[int], None] | None = None
    ) -> None:
        """`progress(m)`: called as the search passes each further `m` bytes of `buf`."""
        self.size = int(buf.size)
        starts, lengths, truncated = _candidates(buf)
        payload = lengths - 2  # bytes under the CRC: STX .. STATUS
        stored = buf[starts + payload].astype(np.uint32) | (
            buf[starts + payload + 1].astype(np.uint32) << 8
        )
        # the CRCs (most of the time) in steps of SEARCH_FRAMES, a multiple of CRC_BLOCK: the
        # same blocks as in one call
        valid = np.empty(starts.size, bool)
        done = 0
        for a in range(0, starts.size, SEARCH_FRAMES):
            b = a + SEARCH_FRAMES
            valid[a:b] = CRC_METHODS[crc](buf, starts[a:b], payload[a:b]) == stored[a:b]
            reached = int(starts[b]) if b < starts.size else self.size
            if progress is not None and reached > done:
                progress(reached - done)
            done = reached
        if progress is not None and done < self.size:
            progress(self.size - done)
        self.start, self.length = _greedy(starts[valid], lengths[valid])
        self.cmd = buf[self.start + 4]
        # candidates outside accepted telegrams: damaged frames (or chance 0x02 0x80 in noise)
        rejected = ~valid & ~_covered(starts, self)
        cut = ~_covered(truncated, self)
        self.rejected_crc = int(np.count_nonzero(rejected))
        self.truncated = int(np.count_nonzero(cut))
        # bytes outside accepted telegrams: inside a rejected telegram's span, or between
        # telegrams (ACK, NAK, line noise)
        gaps = _gap_positions(self.size, self.start, self.length)
        spans_from = np.sort(np.concatenate([starts[rejected], truncated[cut]]))
        ends = np.concatenate([starts[rejected] + lengths[rejected], np.full(cut.sum(), self.size)])
        spans_to = np.sort(ends)
        inside = np.searchsorted(spans_from, gaps, "right") > np.searchsorted(
            spans_to, gaps, "right"
        )
        between = buf[gaps[~inside]]
        self.in_damaged = int(np.count_nonzero(inside))
        self.ack = int(np.count_nonzero(between == ACK))
        self.nak = int(np.count_nonzero(between == NAK))
        self.noise = between.size - self.ack - self.nak
        self.skipped = int(gaps.size)


def _candidates(buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(starts, total lengths) of complete candidate telegrams, and starts of cut-off ones."""
    empty = np.zeros(0, np.int64)
    n = buf.size
    if n < 5:
        return empty, empty, empty
    s = np.flatnonzero(buf[: n - 4] == STX)
    s = s[((buf[s + 1] & 0xFE) == 0x80) & (buf[s + 4] >= 0x80)]
    length = buf[s + 2].astype(np.int64) | (buf[s + 3].astype(np.int64) << 8)
    plausible = (length >= MIN_LEN) & (length <= MAX_LEN)
    s, total = s[plausible], length[plausible] + 6
    complete = s + total <= n
    return s[complete], total[complete], s[~complete]


def _greedy(starts: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep valid telegrams in order; one that starts inside an accepted one is dropped."""
    ends = starts + lengths
    if starts.size < 2 or np.all(starts[1:] >= ends[:-1]):
        return starts, lengths
    keep = np.zeros(starts.size, bool)
    end = -1
    for i, (s, e) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
        if s >= end:
            keep[i] = True
            end = e
    return starts[keep], lengths[keep]


def _covered(positions: np.ndarray, tg: Telegrams) -> np.ndarray:
    """True where a position lies inside an accepted telegram."""
    if tg.start.size == 0 or positions.size == 0:
        return np.zeros(positions.size, bool)
    i = np.searchsorted(tg.start, positions, side="right") - 1
    inside = i >= 0
    j = np.maximum(i, 0)
    return inside & (positions < tg.start[j] + tg.length[j])


def _gap_positions(n: int, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Positions of the bytes outside the accepted telegrams, in order (few: the gaps)."""
    lo = np.concatenate([[0], starts + lengths])
    hi = np.concatenate([starts, [n]])
    size = np.maximum(hi - lo, 0)
    total = int(size.sum())
    return np.repeat(lo - (np.cumsum(size) - size), size) + np.arange(total, dtype=np.int64)


# ---------------------------------------------------------------- measured values


def decode_ranges(buf: np.ndarray, starts: np.ndarray, count: int, scale: float) -> np.ndarray:
    """Ranges (m, S x N float32) of the B0 telegrams at `starts` with `count` values each.

    A sliding-window view of the buffer turns the value bytes of every telegram into one row
    gather, read as little-endian u16 and masked to 13 bits; metres by a float32 division
    (exact integer / exact divisor: correctly rounded), special codes -> NaN; block by
    block, so temporaries stay small.
    """
    divisor = np.float32(round(1 / scale))
    out = np.empty((starts.size, count), np.float32)
    windows = np.lib.stride_tricks.sliding_window_view(buf, 2 * count)
    first = starts + 7
    for a in range(0, starts.size, CHUNK):
        values = windows[first[a : a + CHUNK]].view("<u2") & VALUE_MASK
        block = out[a : a + CHUNK]
        np.divide(values, divisor, out=block, dtype=np.float32)
        np.copyto(block, np.float32(np.nan), where=values >= SPECIAL_MIN)
    return out


def assemble(
    buf: np.ndarray, starts: np.ndarray, part: np.ndarray, count: int, units: str
) -> tuple[np.ndarray, np.ndarray, LaserGeometry, int]:
    """Interlaced mode: P partial scans (index k = offset k x 0.25°) make one scan.

    P = the variant's step / 0.25° (4 at 1°, 2 at 0.5°). A group is P partial telegrams
    with indices 0..P-1, each following the previous one within two telegram lengths (no
    frame lost between them). Beam j*P + k of the scan is value j of partial k: angles from
    the variant's first angle in steps of 0.25°, so N*P beams (724 for 181 values: up to
    90.75°). Returns the groups' first offsets, their ranges, the geometry and how many
    partial telegrams were in no complete group. The 0.25° offsets are this module's
    reading of the count word's bits 11-12 (FORMATS.md names them 'partial-scan index').
    """
    first, step = VARIANTS[count]
    per = round(step / PARTIAL_STEP)
    laser = LaserGeometry(
        count * per, float(np.deg2rad(first)), float(np.deg2rad(PARTIAL_STEP)), RANGE_MAX[units]
    )
    heads = np.arange(max(starts.size - per + 1, 0))
    if per < 2 or heads.size == 0:
        return starts[:0], np.zeros((0, laser.beams), np.float32), laser, int(starts.size)
    near = 2 * (2 * count + 10)
    complete = part[heads] == 0
    for j in range(1, per):
        complete &= (part[heads + j] == j) & (starts[heads + j] - starts[heads + j - 1] < near)
    groups = heads[complete]
    members = (groups[:, None] + np.arange(per)).reshape(-1)
    scale = 0.01 if units == "cm" else 0.001
    values = decode_ranges(buf, starts[members], count, scale)
    ranges = values.reshape(groups.size, per, count).transpose(0, 2, 1).reshape(groups.size, -1)
    return starts[groups], np.ascontiguousarray(ranges), laser, int(starts.size - members.size)


def geometry(count: int, units: str, **mount: float) -> LaserGeometry:
    first, step = VARIANTS[count]
    return LaserGeometry(
        count, float(np.deg2rad(first)), float(np.deg2rad(step)), RANGE_MAX[units], **mount
    )


# ---------------------------------------------------------------- the importer


@dataclass(frozen=True)
class LMS200Options(FormatOptions):
    """Reading an LMS-2xx capture."""

    baud: float = option(
        DEFAULT_BAUD, "line speed for times without a side file or --rate", positive=True
    )
    times: Path | None = option(
        None, "side file of 'OFFSET T' lines", shown="<capture>.times if present"
    )
    crc: Literal["numpy", "numba"] | None = option(
        None, "how the candidates' CRCs are computed", shown="numba from 1 GB"
    )
    rate: float | None = option(
        None, "scans per second (times from the telegrams' order, not the baud)", positive=True
    )


@dataclass(frozen=True)
class LMS200WriteOptions(FormatOptions):
    """Writing an LMS-2xx capture (with optional line damage)."""

    baud: int = option(DEFAULT_BAUD, "line speed (the side file's times)", positive=True)
    units: Literal["cm", "mm"] = option("mm", "cm (80 m, 1 cm) or mm (8 m, 1 mm) mode")
    noise_bytes: float = option(0.0, "mean random bytes between telegrams (Poisson)")
    bit_error_rate: float = option(0.0, "chance of each bit of the stream flipping")
    clock_jitter: float = option(0.0, "s: spread (sd) of the host's times around the scans'")
    truncate_last: bool = option(False, "cut the last telegram short")
    seed: int = option(0, "seed of the damage")
    start_mid_frame: bool = option(False, "begin with the tail of a telegram")
    name: str = option("capture", "file name: NAME.lms, NAME.lms.times, NAME.truth.json")


@register
class LMS200(Importer[LMS200Options, LMS200WriteOptions]):
    name = "lms200"
    summary = "SICK LMS-2xx raw serial capture (.lms/.bin/.raw): telegrams with CRC"
    Options = LMS200Options
    WriteOptions = LMS200WriteOptions

    def sniff(self, path: Path) -> bool:
        capture = _find_capture(path) if path.is_dir() else path
        if capture is None or not capture.is_file():
            return False
        head = np.frombuffer(head_bytes(capture, 8192), np.uint8)
        if head.size == 0:
            return False
        found = Telegrams(head)
        hinted = capture.name.lower().endswith(CAPTURE_SUFFIXES)
        return found.start.size >= (1 if hinted else 2) and bool(found.start[0] < 1024)

    def read(self, sources: Sequence[Path], options: LMS200Options) -> Dataset:
        capture, times_file = _sources(sources, options)
        report = ImportReport()
        buf = _read_capture(capture, report)
        crc = options.crc or default_crc_method(buf.size)
        with task(f"searching {capture.name}", total=buf.size) as (bar, job):
            tg = Telegrams(buf, crc, progress=lambda m: bar.advance(TaskID(job), m))
        report.records_read = int(tg.start.size) + tg.rejected_crc + tg.truncated
        report.drop("telegram CRC mismatch", tg.rejected_crc, _where(capture, "CRC"))
        report.drop("telegram cut off at end of capture", tg.truncated)
        others = Counter(tg.cmd[tg.cmd != MEASURED].tolist())
        for cmd, n in sorted(others.items()):
            report.drop(f"reply 0x{cmd:02X} ({REPLY_NAMES.get(cmd, 'not measured values')})", n)

        s = tg.start[tg.cmd == MEASURED]
        length = tg.length[tg.cmd == MEASURED]
        word = buf[s + 5].astype(np.int64) | (buf[s + 6].astype(np.int64) << 8)
        count, unit_code = word & 0x3FF, word >> 14
        partial, part = ((word >> 13) & 1) == 1, (word >> 11) & 3
        fits = length - 6 >= 2 * count + 4
        known = np.isin(count, list(VARIANTS)) & np.isin(unit_code, list(UNITS))
        usable = fits & known
        report.drop("measured values: count word longer than telegram", int(np.sum(~fits)))
        report.drop("measured values: unknown value count or units", int(np.sum(fits & ~known)))
        interlaced = not np.any(usable & ~partial) and bool(np.any(usable & partial))
        ok = usable & partial if interlaced else usable & ~partial
        report.drop("partial scan among full scans", int(np.sum(usable & partial & ~ok)))
        if not np.any(ok):
            why = ", ".join(f"{n} {reason}" for reason, n in report.dropped.items())
            raise FormatError(
                f"no intact measured-values telegram in {buf.size} bytes"
                + (f" ({why})" if why else ""),
                file=capture,
            )
        variants = Counter(zip(count[ok].tolist(), unit_code[ok].tolist(), strict=True))
        variant = variants.most_common(1)[0][0]
        same = ok & (count == variant[0]) & (unit_code == variant[1])
        report.drop("measured values: variant differs from the capture's", int(np.sum(ok & ~same)))
        units, scale = UNITS[variant[1]]
        if interlaced:
            s, ranges, laser, lost = assemble(buf, s[same], part[same], variant[0], units)
            report.drop("partial scan outside a complete group", lost)
            report.note(f"interlaced capture: {variant[0]} values x {laser.beams // variant[0]} partial scans per scan")  # fmt: skip
            if s.size == 0:
                raise FormatError("no complete group of partial scans", file=capture)
        else:
            s = s[same]
            ranges = decode_ranges(buf, s, variant[0], scale)
            laser = geometry(variant[0], units)
        t, time_source = _times(s, times_file, options, capture)
        order_ok = np.concatenate([[True], np.diff(t) >= 0])
        if not np.all(order_ok):  # a side file out of step with the capture
            keep = order_ok & (t >= np.maximum.accumulate(t))
            report.drop("time goes backwards", int(np.sum(~keep)))
            s, t, ranges = s[keep], t[keep], ranges[keep]
        report.records_kept = int(s.size)
        skipped = tg.skipped
        if skipped:
            report.note(
                f"{skipped} bytes outside intact telegrams skipped: {tg.in_damaged} in rejected "
                f"telegrams, {tg.ack} ACK, {tg.nak} NAK, {tg.noise} line noise"
            )
        sources_used = [capture] + ([times_file] if times_file else [])
        meta = make_meta(
            self.name,
            sources_used,
            laser,
            report,
            time_source=time_source,
            units=units,
            capture={
                "bytes": tg.size,
                "telegrams": int(tg.start.size),
                "measured_values": int(s.size),
                "bytes_in_telegrams": int(tg.length.sum()),
                "bytes_skipped": skipped,
                "bytes_in_rejected_telegrams": tg.in_damaged,
                "noise": tg.noise,
                "ack": tg.ack,
                "nak": tg.nak,
                "crc_rejected": tg.rejected_crc,
                "truncated": tg.truncated,
                "crc_method": crc,
            },
        )
        return Dataset(t=t, ranges=ranges, laser=laser, meta=meta)

    def write(
        self, ds: Dataset, out: Path, options: LMS200WriteOptions | None = None
    ) -> list[Path]:
        o = options or LMS200WriteOptions()
        return write(
            ds, out, baud=o.baud, units=o.units, noise_bytes=o.noise_bytes,
            bit_error_rate=o.bit_error_rate, clock_jitter=o.clock_jitter,
            truncate_last=o.truncate_last, seed=o.seed,
            start_mid_frame=o.start_mid_frame, name=o.name,
        )  # fmt: skip


def _read_capture(path: Path, report: ImportReport) -> np.ndarray:
    """The capture's bytes, decompressed if it is gz/bz2/xz.

    A damaged compressed stream keeps what decompressed before the damage; a file that only
    looks compressed (noise that happens to start with a magic number) is read raw.
    """
    errors = (OSError, EOFError, lzma.LZMAError)
    try:
        with open_binary(path) as f:
            if isinstance(f, io.BufferedReader):  # not compressed: map it, no copy
                size = path.stat().st_size
                return np.memmap(path, np.uint8, "r") if size else np.zeros(0, np.uint8)
            return np.frombuffer(f.read(), np.uint8)
    except errors:
        pass
    parts: list[bytes] = []  # read again block by block to keep what decompresses
    try:
        with open_binary(path) as f:
            while block := f.read(1 << 13):
                parts.append(block)
    except errors as e:
        if not parts:
            report.note(f"starts like a compressed file but does not decompress ({e}): read raw")
            return np.fromfile(path, np.uint8)
        report.note(f"compressed stream damaged after {sum(map(len, parts))} bytes ({e})")
    return np.frombuffer(b"".join(parts), np.uint8)


def _where(path: Path, what: str) -> str:
    return f"{path.name}: {what}"


def _find_capture(directory: Path) -> Path | None:
    files = sorted(
        p for p in directory.iterdir() if p.is_file() and p.name.lower().endswith(CAPTURE_SUFFIXES)
    )
    return files[0] if len(files) == 1 else None


def _sources(sources: Sequence[Path], options: LMS200Options) -> tuple[Path, Path | None]:
    """The capture file and its side file of timestamps (if any)."""
    paths = [Path(p) for p in sources]
    if len(paths) == 1 and paths[0].is_dir():
        capture = _find_capture(paths[0])
        if capture is None:
            raise ToolkitError(
                f"expected one capture ({', '.join(CAPTURE_SUFFIXES)}) in the directory",
                file=paths[0],
            )
        paths = [capture]
    paths = [p for p in paths if not p.name.endswith(TRUTH_SUFFIX)]  # the writer's truth file
    times = [p for p in paths if p.name.endswith(TIMES_SUFFIX)]
    captures = [p for p in paths if p not in times]
    if len(captures) != 1 or len(times) > 1:
        raise ToolkitError("lms200 takes one capture and at most one .times side file")
    capture = captures[0]
    if options.times is not None:
        return capture, options.times
    if times:
        return capture, times[0]
    for candidate in (
        capture.with_name(capture.name + TIMES_SUFFIX),
        capture.with_suffix(TIMES_SUFFIX),
    ):
        if candidate.is_file():
            return capture, candidate
    return capture, None


def read_times(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A side file: (byte offsets, times), offsets strictly increasing."""
    try:
        with open_text(path) as f:
            table = pd.read_csv(
                f, sep=r"\s+", comment="#", header=None, names=["offset", "t"], dtype=float
            )
    except (ValueError, pd.errors.ParserError) as e:
        raise FormatError(f"times side file: expected 'OFFSET T' lines ({e})", file=path) from None
    except pd.errors.EmptyDataError:
        raise FormatError("times side file is empty", file=path) from None
    off, t = table["offset"].to_numpy(), table["t"].to_numpy()
    bad = ~np.isfinite(off) | ~np.isfinite(t)
    if np.any(bad):
        raise FormatError("times side file: missing or non-numeric value", file=path, record=int(np.argmax(bad)) + 1)  # fmt: skip
    if off.size == 0:
        raise FormatError("times side file is empty", file=path)
    if np.any(np.diff(off) <= 0):
        line = int(np.argmax(np.diff(off) <= 0)) + 2
        raise FormatError("times side file: offsets must increase", file=path, record=line)
    return off, t


def _times(
    offsets: np.ndarray, times_file: Path | None, options: LMS200Options, capture: Path
) -> tuple[np.ndarray, str]:
    off = offsets.astype(np.float64)
    if times_file is not None:
        xp, fp = read_times(times_file)
        t = np.interp(off, xp, fp)
        if xp.size >= 2:  # linear extrapolation beyond the ends
            lo, hi = off < xp[0], off > xp[-1]
            t[lo] = fp[0] + (off[lo] - xp[0]) * (fp[1] - fp[0]) / (xp[1] - xp[0])
            t[hi] = fp[-1] + (off[hi] - xp[-1]) * (fp[-1] - fp[-2]) / (xp[-1] - xp[-2])
        return t, f"side file {times_file.name} (byte offset -> time, interpolated)"
    if options.rate:
        spacing = float(np.median(np.diff(off))) if off.size > 1 else 1.0
        slots = np.rint((off - off[0]) / spacing)
        return slots / options.rate, f"rate {options.rate:g} Hz (stated, --rate)"
    baud = options.baud
    return off * BITS_PER_BYTE / baud, f"baud {baud:g} (byte offset x {BITS_PER_BYTE} bits / baud)"


# ---------------------------------------------------------------- writer


def telegram(cmd: int, data: bytes, status: int = 0x10, address: int = 0x80) -> bytes:
    """One reply telegram with its CRC."""
    body = bytes([STX, address]) + (len(data) + 2).to_bytes(2, "little") + bytes([cmd])
    body += data + bytes([status])
    return body + crc16_sick(body).to_bytes(2, "little")


def _variant_of(ds: Dataset) -> int:
    count = ds.n_beams
    first_step = VARIANTS.get(count)
    if first_step is not None:
        first, step = np.deg2rad(first_step)
        if abs(ds.laser.angle_min - first) < 1e-6 and abs(ds.laser.angle_increment - step) < 1e-6:
            return count
    raise ToolkitError(
        f"lms200 writer: {count} beams from {np.rad2deg(ds.laser.angle_min):g}° step "
        f"{np.rad2deg(ds.laser.angle_increment):g}° is no LMS-2xx variant "
        "(181/361 from -90°, 101/201/401 from -50°)"
    )


def encode_values(ranges: np.ndarray, units: str) -> np.ndarray:
    """Ranges (m) to 13-bit values: NaN -> 0x1FFF (invalid), too far -> 0x1FF7 (above maximum)."""
    scale = {"cm": 100.0, "mm": 1000.0}[units]
    with np.errstate(invalid="ignore"):
        v = np.rint(np.asarray(ranges, np.float64) * scale)
        values = np.where(v >= SPECIAL_MIN, 0x1FF7, np.clip(v, 0, None))
    return np.where(np.isnan(v), 0x1FFF, values).astype(np.uint16)


def write(
    ds: Dataset,
    out: Path,
    baud: int = DEFAULT_BAUD,
    units: str = "mm",
    noise_bytes: float = 0.0,
    bit_error_rate: float = 0.0,
    clock_jitter: float = 0.0,
    truncate_last: bool = False,
    seed: int = 0,
    start_mid_frame: bool = False,
    name: str = "capture",
    **opts: object,
) -> list[Path]:
    """Write `ds` as a capture as the host's serial port received it, with optional damage.

    Files under directory `out`: ``<name>.lms`` (an ACK and the mode-change and variant replies,
    then one B0 telegram per scan, a random ACK/NAK byte now and then), ``<name>.lms.times``
    (the side file: STX offset and time of every B0 telegram) and ``<name>.truth.json``
    (``intact``: indices of the scans whose telegrams were written undamaged). `noise_bytes`:
    mean number of random bytes (Poisson) between telegrams; `bit_error_rate`: probability of
    each bit of the stream flipping; `clock_jitter`: the spread (sd, s) of the side file's times
    around the scans' (a host that stamps each read() late by a varying delay: normal, kept in
    order); `truncate_last`: cut the last telegram short;
    `start_mid_frame`: begin with the tail of a telegram.
    """
    if opts:
        known = (
            "baud, units, noise_bytes, bit_error_rate, clock_jitter, truncate_last, seed, "
            "start_mid_frame, name"
        )
        raise ToolkitError(f"lms200 writer: unknown option(s) {', '.join(sorted(opts))}; known: {known}")  # fmt: skip
    if units not in ("cm", "mm"):
        raise ToolkitError(f"lms200 writer: units must be cm or mm, not {units!r}")
    if not noise_bytes >= 0 or not clock_jitter >= 0 or not 0 <= bit_error_rate <= 1:
        raise ToolkitError(
            "lms200 writer: noise_bytes and clock_jitter must be >= 0, bit_error_rate in [0, 1]"
        )
    count = _variant_of(ds)
    rng = np.random.default_rng(seed)
    unit_bits = 0 if units == "cm" else 1
    values = encode_values(ds.ranges, units)
    scans = ds.n_scans
    frame_len = 7 + 2 * count + 1 + 2
    frames = np.empty((scans, frame_len), np.uint8)
    frames[:, 0], frames[:, 1] = STX, 0x80
    frames[:, 2:4] = np.frombuffer((frame_len - 6).to_bytes(2, "little"), np.uint8)
    frames[:, 4] = MEASURED
    frames[:, 5:7] = np.frombuffer((count | unit_bits << 14).to_bytes(2, "little"), np.uint8)
    frames[:, 7 : 7 + 2 * count] = values.astype("<u2").view(np.uint8).reshape(scans, -1)
    frames[:, 7 + 2 * count] = 0x10  # status: ok
    flat = frames.reshape(-1)
    crc_all = CRC_METHODS[default_crc_method(scans * frame_len)]
    crc = crc_all(flat, np.arange(scans) * frame_len, np.full(scans, frame_len - 2))
    frames[:, -2] = crc & 0xFF
    frames[:, -1] = crc >> 8

    first, step = VARIANTS[count]
    head = bytearray()
    if start_mid_frame and scans:
        head += frames[0, int(rng.integers(1, frame_len)) :].tobytes()
    head += bytes([ACK]) + telegram(0xA0, b"\x00")
    angle, resolution = round(2 * abs(first)), round(step * 100)
    reply = b"\x01" + angle.to_bytes(2, "little") + resolution.to_bytes(2, "little")
    head += bytes([ACK]) + telegram(0xBB, reply)
    # gaps between telegrams: Poisson noise bytes, now and then an ACK or NAK
    gap_len = rng.poisson(noise_bytes, scans) if noise_bytes > 0 else np.zeros(scans, np.int64)
    flag = rng.random(scans) < 0.02
    gap_len = gap_len + flag
    gap_total = int(gap_len.sum())
    gap_bytes = rng.integers(0, 256, gap_total, dtype=np.uint8)
    gap_ends = np.cumsum(gap_len)
    gap_bytes[gap_ends[flag] - 1] = np.where(rng.random(int(flag.sum())) < 0.5, ACK, NAK)
    # stream = head, then per scan: gap, frame; frames written as rows of a sliding window
    frame_starts = len(head) + gap_ends + frame_len * np.arange(scans)
    total = len(head) + gap_total + frame_len * scans
    stream = np.empty(total, np.uint8)
    stream[: len(head)] = np.frombuffer(bytes(head), np.uint8)
    if scans:
        windows = np.lib.stride_tricks.sliding_window_view(stream, frame_len, writeable=True)
        windows[frame_starts] = frames
    gap_at = np.repeat(frame_starts - gap_ends, gap_len) + np.arange(gap_total)
    stream[gap_at] = gap_bytes

    damaged = np.zeros(scans, bool)
    if bit_error_rate > 0:
        flips = np.unique(rng.integers(0, total * 8, rng.binomial(total * 8, bit_error_rate)))
        np.bitwise_xor.at(stream, flips // 8, (1 << (flips % 8)).astype(np.uint8))
        k = np.searchsorted(frame_starts, flips // 8, side="right") - 1
        hit = (k >= 0) & (flips // 8 < frame_starts[np.maximum(k, 0)] + frame_len)
        damaged[k[hit]] = True
    if truncate_last and scans:
        total = int(frame_starts[-1] + rng.integers(1, frame_len))
        stream = stream[:total]
        damaged[-1] = True

    # drawn after the damage: a clock's jitter leaves the stream as it was
    stamps = host_stamps(ds.t, clock_jitter, rng)

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    capture = out / f"{name}.lms"
    times = out / f"{name}.lms{TIMES_SUFFIX}"
    truth = out / f"{name}{TRUTH_SUFFIX}"
    with atomic_file(capture) as tmp:
        stream.tofile(tmp)
    with atomic_file(times) as tmp, open(tmp, "w") as f:
        f.write("# OFFSET T: byte offset of each measured-values telegram's STX, time (s)\n")
        np.savetxt(f, np.column_stack([frame_starts, stamps]), fmt=["%d", "%.17g"])
    info = {
        "scans": scans,
        "intact": np.flatnonzero(~damaged).tolist(),
        "damaged": np.flatnonzero(damaged).tolist(),
        "frame_offsets": frame_starts.tolist(),
        "baud": baud,
        "units": units,
        "noise_bytes": noise_bytes,
        "bit_error_rate": bit_error_rate,
        "clock_jitter": clock_jitter,
        "truncate_last": truncate_last,
        "start_mid_frame": start_mid_frame,
        "seed": seed,
    }
    with atomic_file(truth) as tmp:
        tmp.write_text(json.dumps(info) + "\n")
    return [capture, times, truth]
