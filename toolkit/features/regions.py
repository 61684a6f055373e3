"""Training regions: a CSV `feature,start,end`, one row per span of scans (inclusive, in the
dataset's time base). Several rows may teach the same feature.

Every problem is one line naming the CSV row (its line number in the file, the header being
line 1): unknown or missing columns, non-numeric times, start after end, spans outside the log,
spans that hold no scan, and overlapping spans of different features.
"""

from __future__ import annotations

import csv
import os
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from toolkit.errors import FormatError

COLUMNS = ("feature", "start", "end")
NONE_LABEL = "none"


@dataclass(frozen=True)
class Span:
    """One training span: the scans with start <= t <= end teach `feature`."""

    feature: str
    start: float
    end: float
    line: int  # line in the CSV (header = 1); 0 for spans made in code
    first: int  # index of the first scan in the span
    last: int  # index of the last scan (inclusive)

    @property
    def indices(self) -> np.ndarray:
        return np.arange(self.first, self.last + 1)

    @property
    def scans(self) -> int:
        return self.last - self.first + 1

    def to_dict(self) -> dict[str, float | int | str]:
        return {"feature": self.feature, "start": self.start, "end": self.end, "scans": self.scans}


def _tolerance(t: np.ndarray) -> float:
    """Slack for times printed with fewer digits than the log holds (CSV round trips)."""
    scale = float(np.max(np.abs(t))) if len(t) else 1.0
    return max(1e-6, 1e-12 * scale)


MAX_BYTES = 16 << 20  # a regions CSV names a few spans: far below this


def _read_text(path: Path) -> str:
    """The file as UTF-8 text; what is no text file (a PNG, a FIFO, a huge file) is a
    one-line error."""
    try:
        mode = os.stat(path).st_mode
        if not stat.S_ISREG(mode):
            kind = "a directory" if stat.S_ISDIR(mode) else "not a regular file (FIFO, device)"
            raise FormatError(f"is {kind}; expected a CSV file", file=path)
        if os.stat(path).st_size > MAX_BYTES:
            raise FormatError(f"larger than {MAX_BYTES >> 20} MB; not a regions CSV", file=path)
        data = path.read_bytes()
    except OSError as e:
        raise FormatError(f"cannot read: {e.strerror}", file=path) from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise FormatError(
            f"not a text CSV (byte 0x{data[e.start]:02x} at offset {e.start}: an image?)",
            file=path,
        ) from None
    if "\x00" in text:
        raise FormatError("not a text CSV (NUL byte)", file=path)
    return text


def read_regions(path: str | Path, t: np.ndarray) -> list[Span]:
    """Read and check a regions CSV against the scan times `t` (non-decreasing)."""
    path = Path(path)
    text = _read_text(path)
    try:
        rows = list(csv.reader(text.splitlines()))
    except csv.Error as e:
        raise FormatError(f"not a CSV: {e}", file=path) from None
    if not rows or not any(cell.strip() for cell in rows[0]):
        raise FormatError("empty file; expected a header feature,start,end", file=path, record=1)
    header = [c.strip().lower() for c in rows[0]]
    unknown = [c for c in header if c not in COLUMNS]
    if unknown:
        raise FormatError(
            f"unknown column {unknown[0]!r}; expected feature,start,end", file=path, record=1
        )
    missing = [c for c in COLUMNS if c not in header]
    if missing or len(header) != len(set(header)):
        what = f"missing column {missing[0]!r}" if missing else "repeated column"
        raise FormatError(f"{what}; expected feature,start,end", file=path, record=1)
    where = {c: header.index(c) for c in COLUMNS}
    tol = _tolerance(t)
    spans: list[Span] = []
    for line, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise FormatError(
                f"{len(row)} fields, the header has {len(header)}", file=path, record=line
            )
        feature = row[where["feature"]].strip()
        if not feature:
            raise FormatError("empty feature name", file=path, record=line)
        if feature == NONE_LABEL:
            raise FormatError(
                f"{NONE_LABEL!r} is reserved for scans that fit no feature", file=path, record=line
            )
        values = []
        for column in ("start", "end"):
            cell = row[where[column]].strip()
            try:
                value = float(cell)
            except ValueError:
                raise FormatError(
                    f"{column} {cell!r} is not a number", file=path, record=line
                ) from None
            if not np.isfinite(value):
                raise FormatError(f"{column} {cell!r} is not a finite time", file=path, record=line)
            values.append(value)
        start, end = values
        if start > end:
            raise FormatError(f"start {start} is after end {end}", file=path, record=line)
        if len(t) == 0 or start < t[0] - tol or end > t[-1] + tol:
            lo, hi = (t[0], t[-1]) if len(t) else (float("nan"), float("nan"))
            raise FormatError(
                f"span {start}..{end} is outside the log ({lo}..{hi})", file=path, record=line
            )
        first = int(np.searchsorted(t, start - tol, side="left"))
        last = int(np.searchsorted(t, end + tol, side="right")) - 1
        if last < first:
            raise FormatError(f"span {start}..{end} holds no scan", file=path, record=line)
        spans.append(Span(feature, start, end, line, first, last))
    if not spans:
        raise FormatError("no training spans", file=path)
    _check_overlaps(spans, path)
    return spans


def _check_overlaps(spans: list[Span], path: Path) -> None:
    """Spans of different features must not share a scan (one scan, one truth)."""
    ordered = sorted(spans, key=lambda s: (s.first, s.last))
    reach: Span | None = None  # the span reaching furthest so far
    for span in ordered:
        if reach is not None and span.first <= reach.last and span.feature != reach.feature:
            later, earlier = (span, reach) if span.line > reach.line else (reach, span)
            raise FormatError(
                f"span of {later.feature!r} overlaps the span of {earlier.feature!r} "
                f"on line {earlier.line}",
                file=path,
                record=later.line,
            )
        if reach is None or span.last > reach.last:
            reach = span


def spans_from_frame(frame: pd.DataFrame, t: np.ndarray) -> list[Span]:
    """Spans from a DataFrame feature,start,end (e.g. the simulator's `regions`)."""
    tol = _tolerance(t)
    spans = []
    features = frame["feature"].astype(str).tolist()
    starts = frame["start"].to_numpy(np.float64)
    ends = frame["end"].to_numpy(np.float64)
    for k, (feature, start, end) in enumerate(zip(features, starts, ends, strict=True), start=2):
        first = int(np.searchsorted(t, start - tol, side="left"))
        last = int(np.searchsorted(t, end + tol, side="right")) - 1
        if last < first:
            raise FormatError(f"span {start}..{end} holds no scan", record=k)
        spans.append(Span(feature, float(start), float(end), k, first, last))
    _check_overlaps(spans, Path("regions"))
    return spans


def training_indices(spans: list[Span]) -> dict[str, np.ndarray]:
    """Scan indices per feature, in order of first appearance, duplicates removed."""
    out: dict[str, list[np.ndarray]] = {}
    for span in spans:
        out.setdefault(span.feature, []).append(span.indices)
    return {f: np.unique(np.concatenate(parts)) for f, parts in out.items()}


def training_components(spans: list[Span]) -> list[tuple[str, np.ndarray]]:
    """One component per stretch of scans: spans of a feature that overlap or touch are one
    component, separate spans (another corridor, another room) are components of their own."""
    out: list[tuple[str, np.ndarray]] = []
    for feature in dict.fromkeys(s.feature for s in spans):
        mine = sorted((s.first, s.last) for s in spans if s.feature == feature)
        first, last = mine[0]
        for a, b in mine[1:]:
            if a <= last + 1:
                last = max(last, b)
            else:
                out.append((feature, np.arange(first, last + 1)))
                first, last = a, b
        out.append((feature, np.arange(first, last + 1)))
    return out
