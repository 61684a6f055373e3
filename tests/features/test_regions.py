"""Regions CSV: the spans that teach features, and a one-line error naming the row for
every way a CSV can be wrong."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from toolkit.errors import FormatError
from toolkit.features.regions import read_regions, training_components, training_indices

T = 100.0 + 0.2 * np.arange(50)  # scans at 100.0, 100.2, ... 109.8


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "regions.csv"
    path.write_text(text)
    return path


def test_spans_select_scans_inclusive_and_merge_per_feature(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "feature,start,end\ndoor,100.2,100.6\nroom,105,105.8\ndoor,101.0,101.2\ndoor,100.6,100.8\n",
    )
    spans = read_regions(path, T)
    assert [s.line for s in spans] == [2, 3, 4, 5]
    assert spans[0].indices.tolist() == [1, 2, 3]  # both ends inclusive
    idx = training_indices(spans)
    assert list(idx) == ["door", "room"]
    assert idx["door"].tolist() == [1, 2, 3, 4, 5, 6]  # overlap of one feature: allowed, merged
    assert idx["room"].tolist() == [25, 26, 27, 28, 29]


def test_times_printed_with_fewer_digits_still_match(tmp_path: Path) -> None:
    t = 1_700_000_000.123456789 + 0.1 * np.arange(20)
    path = write(tmp_path, f"feature,start,end\na,{t[3]:.6f},{t[5]:.6f}\n")
    assert read_regions(path, t)[0].indices.tolist() == [3, 4, 5]


def test_column_order_and_case_do_not_matter(tmp_path: Path) -> None:
    path = write(tmp_path, "End,Feature,Start\n100.4,door,100.0\n")
    assert read_regions(path, T)[0].indices.tolist() == [0, 1, 2]


@pytest.mark.parametrize(
    ("text", "line", "needle"),
    [
        ("feature,start,end,colour\ndoor,100,101,red\n", 1, "unknown column 'colour'"),
        ("feature,start\ndoor,100\n", 1, "missing column 'end'"),
        ("feature,start,end\ndoor,100.05,100.15\n", 2, "holds no scan"),
        ("feature,start,end\ndoor,100,101\nroom,100.8,102\n", 3, "overlaps the span of 'door' on line 2"),
        ("feature,start,end\ndoor,100,101\nroom,99,100.5\n", 3, "outside the log"),
        ("feature,start,end\ndoor,109,111\n", 2, "outside the log"),
        ("feature,start,end\ndoor,101,100\n", 2, "start 101.0 is after end 100.0"),
        ("feature,start,end\ndoor,abc,101\n", 2, "start 'abc' is not a number"),
        ("feature,start,end\ndoor,100,\n", 2, "end '' is not a number"),
        ("feature,start,end\ndoor,100,nan\n", 2, "not a finite time"),
        ("feature,start,end\n,100,101\n", 2, "empty feature name"),
        ("feature,start,end\nnone,100,101\n", 2, "reserved"),
        ("feature,start,end\ndoor,100,101,7\n", 2, "4 fields"),
        ("feature,start,end\n", None, "no training spans"),
        ("", 1, "empty file"),
    ],
)  # fmt: skip
def test_bad_csv_is_one_line_naming_the_row(
    tmp_path: Path, text: str, line: int | None, needle: str
) -> None:
    path = write(tmp_path, text)
    with pytest.raises(FormatError) as err:
        read_regions(path, T)
    message = err.value.line()
    assert "\n" not in message
    assert needle in message
    prefix = f"{path}:{line}: " if line is not None else f"{path}: "
    assert message.startswith(prefix), message


def test_separate_spans_of_a_feature_are_components(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "feature,start,end\ncorridor,100,100.4\nroom,101.4,101.8\ncorridor,100.6,101.0\n"
        "corridor,105,105.4\n",
    )
    parts = [(f, idx.tolist()) for f, idx in training_components(read_regions(path, T))]
    # touching spans (scans 0-2 and 3-5) are one stretch; a distant span is a component apart
    assert parts == [
        ("corridor", [0, 1, 2, 3, 4, 5]),
        ("corridor", [25, 26, 27]),
        ("room", [7, 8, 9]),
    ]
