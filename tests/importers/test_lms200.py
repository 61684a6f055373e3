"""SICK LMS-2xx raw captures: CRC test vectors, telegram search on clean and damaged captures
written by the module's own writer (its truth file says which frames are intact), hand-built
telegrams for the decoding rules, time sources, sniffing, damaged-input properties and the CLI.

No real LMS-200 capture exists in ../shared/data/real, so the fixtures are generated."""

from __future__ import annotations

import gzip
import json
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from rich.progress import TaskID

import importers
from importers import lms200
from importers.lms200 import (
    LMS200,
    LMS200Options,
    Telegrams,
    crc16_sick,
    crc_frames_numba,
    crc_frames_numpy,
    read_times,
    telegram,
    write,
)
from tests.conftest import Cli
from tests.importers.checks import assert_bad_input_is_one_line
from tests.test_progress import Recording
from toolkit.dataset import Dataset, LaserGeometry, load
from toolkit.errors import FormatError, ToolkitError

VECTORS = [  # FORMATS.md: whole telegrams, CRC last, low byte first
    "02 00 01 00 31 15 12",
    "02 00 02 00 20 24 34 08",
    "02 00 05 00 3B B4 00 64 00 97 49",
    "02 80 03 00 A0 00 10 16 0A",
]


def _dataset(scans: int = 60, beams: int = 361, seed: int = 0, far: float = 9.0) -> Dataset:
    """Ranges up to `far` m (beyond the 8.18 m of mm mode, so some read as 'above maximum')."""
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.05, far, (scans, beams)).astype(np.float32)
    ranges[:, 7] = np.nan
    first, step = {181: (-90, 1), 361: (-90, 0.5), 101: (-50, 1), 201: (-50, 0.5), 401: (-50, 0.25)}[beams]  # fmt: skip
    laser = LaserGeometry(beams, np.deg2rad(first), np.deg2rad(step), 8.191)
    return Dataset(t=1000.0 + np.arange(scans) / 75.0, ranges=ranges, laser=laser)


def _expected(ds: Dataset, units: str = "mm") -> np.ndarray:
    """What the scanner would report for `ds`: quantised, NaN beyond the last data value."""
    scale = 1000.0 if units == "mm" else 100.0
    counts = np.rint(ds.ranges.astype(np.float64) * scale)
    return np.where(counts >= 0x1FF7, np.nan, counts / scale).astype(np.float32)


def _read(*sources: Path, **extra: str) -> Dataset:
    return LMS200().read(list(sources), LMS200Options.parse(extra))


# ---------------------------------------------------------------- CRC


@pytest.mark.parametrize("vector", VECTORS)
@pytest.mark.parametrize("method", ["reference", "numpy", "numba"])
def test_crc_test_vectors(vector: str, method: str) -> None:
    data = bytes.fromhex(vector)
    want = int.from_bytes(data[-2:], "little")
    if method == "reference":
        assert crc16_sick(data[:-2]) == want
    else:
        fn = crc_frames_numpy if method == "numpy" else crc_frames_numba
        buf = np.frombuffer(data, np.uint8)
        assert fn(buf, np.array([0]), np.array([len(data) - 2])).tolist() == [want]


def test_crc_across_frames_matches_the_reference_for_mixed_lengths() -> None:
    rng = np.random.default_rng(3)
    buf = rng.integers(0, 256, 50_000, dtype=np.uint8)
    starts = np.sort(rng.integers(0, 49_000, 300))
    lengths = rng.integers(1, 811, 300)
    lengths = np.minimum(lengths, buf.size - starts)
    want = [crc16_sick(buf[s : s + n]) for s, n in zip(starts, lengths, strict=True)]
    assert crc_frames_numpy(buf, starts, lengths).tolist() == want
    assert crc_frames_numba(buf, starts, lengths).tolist() == want


# ---------------------------------------------------------------- clean captures


@pytest.mark.parametrize(
    ("beams", "units", "first_deg", "step_deg", "range_max"),
    [
        (361, "mm", -90, 0.5, 8.191),
        (181, "cm", -90, 1.0, 81.91),
        (101, "mm", -50, 1.0, 8.191),
        (401, "cm", -50, 0.25, 81.91),
    ],
)
def test_clean_capture_round_trip(
    tmp_path: Path, beams: int, units: str, first_deg: float, step_deg: float, range_max: float
) -> None:
    ds = _dataset(beams=beams, far=9.0 if units == "mm" else 90.0)
    capture, _, truth = write(ds, tmp_path, units=units)
    back = _read(capture)
    assert json.loads(truth.read_text())["intact"] == list(range(ds.n_scans))
    assert back.n_scans == ds.n_scans and back.n_beams == beams
    np.testing.assert_allclose(np.rad2deg(back.laser.angle_min), first_deg)
    np.testing.assert_allclose(np.rad2deg(back.laser.angle_increment), step_deg)
    assert back.laser.range_max == range_max and back.meta["units"] == units
    np.testing.assert_array_equal(back.t, ds.t)  # the side file, found beside the capture
    assert "side file" in back.meta["time_source"]
    np.testing.assert_allclose(back.ranges, _expected(ds, units), rtol=0, atol=1e-6)
    assert np.isnan(back.ranges[:, 7]).all()
    if units == "mm":  # ranges beyond 8.183 m were written as 'above maximum' codes
        assert np.isnan(back.ranges).sum() > ds.n_scans
    report = back.meta["import_report"]
    assert report["records_kept"] == ds.n_scans
    assert report["dropped"] == {"reply 0xA0 (mode change)": 1, "reply 0xBB (variant)": 1}
    assert back.odometry is None


def _b0(values: list[int], count_word: int | None = None, address: int = 0x80) -> bytes:
    word = len(values) | (1 << 14) if count_word is None else count_word
    data = word.to_bytes(2, "little") + b"".join(v.to_bytes(2, "little") for v in values)
    return telegram(0xB0, data, address=address)


def test_hand_built_telegram_values_flags_and_special_codes(tmp_path: Path) -> None:
    values = [1000 + i for i in range(181)]
    codes = [0x1FFF, 0x1FFE, 0x1FFD, 0x1FFB, 0x1FFA, 0x1FF7]
    values[10 : 10 + len(codes)] = codes
    values[20] = 1234 | 0xE000  # field / dazzle flags in the top 3 bits: not part of the range
    cm = [500] * 181
    cm_word = 181  # bits 14-15 = 00: cm
    path = tmp_path / "hand.lms"
    # the second telegram from address 0x81 (as in the manual's examples)
    path.write_bytes(
        b"\x06" + _b0(values) + b"\x15\xff" + _b0(values, address=0x81) + _b0(cm, cm_word)
    )
    back = _read(path)
    # the cm scan is a different variant: dropped, counted; the mm scans kept
    assert back.n_scans == 2 and back.meta["units"] == "mm"
    row = back.ranges[0]
    assert np.isnan(row[10:16]).all() and np.isfinite(np.delete(row, range(10, 16))).all()
    assert row[0] == np.float32(1.0) and row[180] == np.float32(1.180)
    assert row[20] == np.float32(1.234)
    report = back.meta["import_report"]
    assert report["dropped"] == {"measured values: variant differs from the capture's": 1}
    cap = back.meta["capture"]
    assert (cap["ack"], cap["nak"], cap["noise"], cap["telegrams"]) == (1, 1, 1, 3)
    assert cap["bytes_skipped"] == 3 and cap["bytes_in_rejected_telegrams"] == 0
    assert back.meta["time_source"].startswith("baud 38400")
    frame = len(_b0(values))
    np.testing.assert_allclose(back.t, np.array([1, 1 + frame + 2]) * 10 / 38400)


def test_partial_scans_other_replies_and_bad_count_words_are_reported(tmp_path: Path) -> None:
    values = [2000] * 101
    partial = 101 | (1 << 14) | (1 << 13) | (1 << 11)  # partial scan, index 1
    too_long = 103 | (1 << 14)  # count word claims more values than the telegram holds
    odd_units = 101 | (3 << 14)
    path = tmp_path / "mixed.bin"
    path.write_bytes(
        _b0(values)
        + _b0(values, partial)
        + telegram(0x92, b"")
        + _b0(values, too_long)
        + _b0(values, odd_units)
        + _b0(values)
    )
    back = _read(path)
    assert back.n_scans == 2 and np.all(back.ranges == np.float32(2.0))
    assert np.rad2deg(back.laser.angle_min) == pytest.approx(-50)
    assert back.meta["import_report"]["dropped"] == {
        "reply 0x92 (command rejected)": 1,
        "measured values: count word longer than telegram": 1,
        "partial scan among full scans": 1,
        "measured values: unknown value count or units": 1,
    }


def test_interlaced_capture_is_assembled_from_complete_groups(tmp_path: Path) -> None:
    def part(
        k: int, scan: int
    ) -> bytes:  # value j of partial k of a scan: 1000 + 100 scan + 4 j + k
        word = 181 | (1 << 14) | (1 << 13) | (k << 11)
        return _b0([1000 + 100 * scan + 4 * j + k for j in range(181)], word)

    damaged = bytearray(part(2, 1))
    damaged[50] ^= 0x10
    path = tmp_path / "interlaced.lms"
    path.write_bytes(
        part(2, 9) + part(3, 9)  # the end of a group: the capture started mid-scan
        + b"".join(part(k, 0) for k in range(4))
        + part(0, 1) + part(1, 1) + bytes(damaged) + part(3, 1)  # a partial lost to damage
        + part(0, 2) + part(1, 2) + b"\x06" + part(2, 2) + part(3, 2)
    )  # fmt: skip
    back = _read(path)
    assert back.ranges.shape == (2, 724)
    np.testing.assert_allclose(np.rad2deg(back.angles[[0, 1, 4, 723]]), [-90, -89.75, -89, 90.75])
    beam = np.arange(724)
    for row, scan in zip(back.ranges, (0, 2), strict=True):
        np.testing.assert_allclose(row, (1000 + 100 * scan + beam) / 1000, rtol=1e-6)
    report = back.meta["import_report"]
    assert report["dropped"]["partial scan outside a complete group"] == 2 + 3
    assert report["dropped"]["telegram CRC mismatch"] == 1


def test_capture_of_unusable_telegrams_says_why_it_has_no_scan(tmp_path: Path) -> None:
    path = tmp_path / "odd.lms"
    path.write_bytes(_b0([900] * 180) + _b0([900] * 181, 181 | (3 << 14)))
    with pytest.raises(FormatError, match=r"\(2 measured values: unknown value count or units\)"):
        _read(path)


def test_valid_telegram_inside_another_is_consumed_by_it(tmp_path: Path) -> None:
    inner = bytes.fromhex(VECTORS[3])  # a complete, valid A0 reply
    raw = bytearray((1000).to_bytes(2, "little") * 181)
    raw[100 : 100 + len(inner)] = inner
    outer = telegram(0xB0, (181 | 1 << 14).to_bytes(2, "little") + bytes(raw))
    path = tmp_path / "nested.lms"
    path.write_bytes(inner + outer)
    tg = Telegrams(np.frombuffer(path.read_bytes(), np.uint8))
    assert tg.start.tolist() == [0, len(inner)]  # the nested copy is not a telegram
    assert tg.cmd.tolist() == [0xA0, 0xB0] and tg.skipped == 0
    back = _read(path)
    assert back.n_scans == 1 and back.meta["import_report"]["dropped"] == {
        "reply 0xA0 (mode change)": 1
    }


# ---------------------------------------------------------------- damaged captures


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_damaged_capture_imports_exactly_its_intact_frames(tmp_path: Path, seed: int) -> None:
    ds = _dataset(scans=400, beams=181, seed=seed)
    capture, _, truth_file = write(
        ds, tmp_path, noise_bytes=6.0, bit_error_rate=2e-5, truncate_last=True,
        start_mid_frame=True, seed=seed,
    )  # fmt: skip
    truth = json.loads(truth_file.read_text())
    intact = np.array(truth["intact"])
    assert 300 < intact.size < 399 and ds.n_scans - 1 in truth["damaged"]
    back = _read(capture)
    np.testing.assert_array_equal(back.t, ds.t[intact])
    np.testing.assert_allclose(back.ranges, _expected(ds)[intact], rtol=0, atol=1e-6)
    report = back.meta["import_report"]
    assert report["records_kept"] == intact.size
    assert report["dropped"]["telegram cut off at end of capture"] == 1
    # every damaged frame that still shows its header is rejected by its CRC
    assert 0 < report["dropped"]["telegram CRC mismatch"] <= len(truth["damaged"]) + 5
    cap = back.meta["capture"]
    assert cap["bytes_skipped"] > 6 * ds.n_scans * 0.8 and cap["ack"] + cap["nak"] > 0
    assert cap["bytes"] == capture.stat().st_size
    assert any("bytes outside intact telegrams skipped" in n for n in report["notes"])


def test_a_jittered_host_clock_changes_the_side_file_alone(tmp_path: Path) -> None:
    """`clock_jitter`: the side file's times spread around the scans' by about that sd and
    stay in order; the stream is the one written without it, damage included."""
    ds = _dataset(scans=400, beams=181)
    period = 1 / 75.0
    plain, _, _ = write(ds, tmp_path / "plain", bit_error_rate=2e-5, seed=3)
    capture, times, truth = write(
        ds, tmp_path / "jitter", bit_error_rate=2e-5, clock_jitter=0.15 * period, seed=3
    )
    assert capture.read_bytes() == plain.read_bytes()
    stamps = np.loadtxt(times)[:, 1]
    assert np.all(np.diff(stamps) >= 0)
    assert 0.12 * period < np.std(stamps - ds.t) < 0.18 * period
    intact = np.array(json.loads(truth.read_text())["intact"])
    np.testing.assert_array_equal(_read(capture).t, stamps[intact])
    with pytest.raises(ToolkitError, match="clock_jitter"):
        write(ds, tmp_path / "bad", clock_jitter=-1.0)


def test_time_sources(tmp_path: Path) -> None:
    ds = _dataset(scans=50, beams=181)
    capture, times, truth_file = write(ds, tmp_path, noise_bytes=4.0, bit_error_rate=5e-5, seed=4)
    truth = json.loads(truth_file.read_text())
    intact = np.array(truth["intact"])
    offsets = np.array(truth["frame_offsets"])[intact]
    assert intact.size < ds.n_scans  # some frames were damaged: gaps
    moved = tmp_path / "elsewhere.times"
    times.rename(moved)
    by_baud = _read(capture, baud="9600")
    np.testing.assert_allclose(by_baud.t, offsets * 10 / 9600)
    assert by_baud.meta["time_source"].startswith("baud 9600")
    by_rate = LMS200().read([capture], LMS200Options(rate=75.0))
    np.testing.assert_allclose(by_rate.t, intact / 75.0, atol=1e-9)  # gaps stay gaps
    assert by_rate.meta["time_source"].startswith("rate 75")
    by_file = _read(capture, moved, truth_file)  # the writer's truth file is ignored
    np.testing.assert_array_equal(by_file.t, ds.t[intact])
    # offsets read back, and a side file that covers only part of the capture extrapolates
    xp, _ = read_times(moved)
    np.testing.assert_array_equal(xp, truth["frame_offsets"])
    part = tmp_path / "part.times"
    part.write_text(f"{xp[10]:.0f} 5.0\n{xp[20]:.0f} 6.0\n")
    partial = _read(capture, times=str(part))
    slope = 1.0 / (xp[20] - xp[10])
    np.testing.assert_allclose(partial.t, 5.0 + (offsets - xp[10]) * slope)


@pytest.mark.parametrize(
    ("content", "message"),
    [("x", "expected 'OFFSET T'"), ("", "empty"), ("5 1\n3 2\n", "offsets must increase")],
)
def test_bad_side_file_is_one_clear_error(tmp_path: Path, content: str, message: str) -> None:
    capture, _, _ = write(_dataset(scans=5, beams=181), tmp_path)
    bad = tmp_path / "bad.times"
    bad.write_text(content)
    with pytest.raises(FormatError, match=message):
        _read(capture, bad)


@cache
def _sample() -> tuple[bytes, np.ndarray]:
    """A small capture (30 scans, mm) and the rows it holds, as decoded ranges."""
    import tempfile

    ds = _dataset(scans=30, beams=181, seed=7)
    with tempfile.TemporaryDirectory() as d:
        capture, _, _ = write(ds, Path(d), noise_bytes=2.0)
        return capture.read_bytes(), _expected(ds)


def _crc_blind(data: bytes, damaged: bytes) -> int:
    """Frames that bit flips changed while their CRC still checks: SICK's CRC feeds every
    byte in twice (as it is and, shifted, with the next), so some flips cancel (bits 760 and
    796 of the sample's first frame: the same CRC); no reader can tell those from intact."""
    length = 2 * 181 + 4
    header = b"\x02\x80" + length.to_bytes(2, "little") + b"\xb0"
    blind = 0
    for at in (m.start() for m in re.finditer(re.escape(header), data)):
        frame, crc = damaged[at : at + 4 + length], damaged[at + 4 + length : at + 6 + length]
        if frame != data[at : at + 4 + length] and crc16_sick(frame) == int.from_bytes(
            crc, "little"
        ):
            blind += 1
    return blind


_mutation = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0, 1)),
    st.tuples(st.just("flip"), st.lists(st.integers(0, 10**9), min_size=1, max_size=12)),
    st.tuples(st.just("prefix"), st.binary(min_size=1, max_size=900)),
    st.tuples(st.just("empty"), st.none()),
    st.tuples(st.just("count"), st.integers(0, 0xFFFF)),
    st.tuples(st.just("splice"), st.binary(min_size=1, max_size=64)),
)


def _damage(data: bytes, kind: str, arg: object) -> bytes:
    buf = bytearray(data)
    if kind == "truncate":
        return bytes(buf[: int(len(buf) * float(arg))])  # type: ignore[arg-type]
    if kind == "flip":
        for bit in arg:  # type: ignore[attr-defined]
            buf[(bit // 8) % len(buf)] ^= 1 << (bit % 8)
        return bytes(buf)
    if kind == "prefix":
        return bytes(arg) + data  # type: ignore[call-overload]
    if kind == "empty":
        return b""
    if kind == "count":  # a huge or odd count word, with a CRC made valid again
        length = 2 * 181 + 4
        at = data.index(b"\x02\x80" + length.to_bytes(2, "little") + b"\xb0")
        buf[at + 5 : at + 7] = int(arg).to_bytes(2, "little")  # type: ignore[call-overload]
        crc = crc16_sick(buf[at : at + 4 + length])
        buf[at + 4 + length : at + 6 + length] = crc.to_bytes(2, "little")
        return bytes(buf)
    middle = len(buf) // 2
    return bytes(buf[:middle]) + bytes(arg) + bytes(buf[middle:])  # type: ignore[call-overload]


@settings(
    max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(mutation=_mutation)
@example(mutation=("flip", [760, 796]))  # a change SICK's CRC cannot see (`_crc_blind`)
def test_damaged_input_never_crashes_nor_yields_a_corrupt_scan(
    tmp_path: Path, mutation: tuple[str, object]
) -> None:
    data, rows = _sample()
    path = tmp_path / "damaged.lms"
    path.write_bytes(_damage(data, *mutation))
    try:
        back = _read(path)
    except ToolkitError:
        return
    known = {rows[i].tobytes(): i for i in range(len(rows))}
    found = [known.get(r.tobytes()) for r in back.ranges]  # NaN patterns compare bytewise
    indices = [i for i in found if i is not None]
    undetectable = _crc_blind(data, _damage(data, *mutation)) if mutation[0] == "flip" else 0
    assert len(found) - len(indices) <= undetectable, "a scan that is no intact frame was accepted"
    assert indices == sorted(indices) and back.n_beams == 181
    assert np.all(np.diff(back.t) > 0)
    report = back.meta["import_report"]
    assert report["records_kept"] == back.n_scans <= report["records_read"]


def test_writer_refuses_unknown_options_and_non_lms_geometry(tmp_path: Path) -> None:
    ds = _dataset(scans=3, beams=181)
    with pytest.raises(ToolkitError, match="unknown option"):
        write(ds, tmp_path, bits=7)
    odd = Dataset(t=ds.t, ranges=ds.ranges[:, :180], laser=LaserGeometry.sick_180(180))
    with pytest.raises(ToolkitError, match="no LMS-2xx variant"):
        write(odd, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_compressed_and_cut_compressed_captures(tmp_path: Path) -> None:
    ds = _dataset(scans=200, beams=181)
    capture, _, _ = write(ds, tmp_path / "w")
    whole = gzip.compress(capture.read_bytes())
    (tmp_path / "c.lms.gz").write_bytes(whole)
    (tmp_path / "cut.lms.gz").write_bytes(whole[: len(whole) // 2])
    back = _read(tmp_path / "c.lms.gz")
    np.testing.assert_allclose(back.ranges, _expected(ds), rtol=0, atol=1e-6)
    cut = _read(tmp_path / "cut.lms.gz")  # what decompressed before the cut is kept
    assert 0 < cut.n_scans < ds.n_scans
    np.testing.assert_allclose(cut.ranges, _expected(ds)[: cut.n_scans], rtol=0, atol=1e-6)
    assert any("compressed stream damaged" in n for n in cut.meta["import_report"]["notes"])


def test_fatal_input_leaves_no_partial_dataset(tmp_path: Path) -> None:
    empty = tmp_path / "empty.lms"
    empty.write_bytes(b"")
    noise = tmp_path / "noise.lms"
    noise.write_bytes(np.random.default_rng(0).integers(0, 256, 20000, dtype=np.uint8).tobytes())
    for src in (empty, noise):
        with pytest.raises(FormatError, match="no intact measured-values telegram"):
            importers.import_log("lms200", [src], tmp_path / "out")
        assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.lms", "noise.lms"]


# ---------------------------------------------------------------- sniffing and the CLI


def test_sniff_and_detect(tmp_path: Path) -> None:
    capture, _, _ = write(_dataset(scans=10, beams=361), tmp_path / "c", start_mid_frame=True)
    renamed = tmp_path / "capture.dat"  # no hinting extension: needs two valid telegrams
    renamed.write_bytes(capture.read_bytes())
    assert importers.detect([capture]).name == "lms200"
    assert importers.detect([renamed]).name == "lms200"
    assert LMS200().sniff(tmp_path / "c")  # the writer's directory
    rng = np.random.default_rng(1)
    (tmp_path / "random.bin").write_bytes(rng.integers(0, 256, 5000, dtype=np.uint8).tobytes())
    (tmp_path / "log.2d").write_text("LaserOdometryLog\nversion: 4\nsick1conf: -90 90 181\n")
    assert not LMS200().sniff(tmp_path / "random.bin")
    assert not LMS200().sniff(tmp_path / "log.2d")
    one = tmp_path / "one.dat"
    one.write_bytes(bytes.fromhex(VECTORS[3]))
    assert not LMS200().sniff(one)  # one telegram, no hint: not enough


def test_cli_import_lms200_and_auto(tmp_path: Path, cli: Cli) -> None:
    ds = _dataset(scans=40, beams=361)
    capture, _, truth = write(ds, tmp_path / "w", noise_bytes=3.0, bit_error_rate=3e-5, seed=2)
    intact = json.loads(truth.read_text())["intact"]
    for fmt in ("lms200", "auto"):
        out = tmp_path / fmt
        code, stdout, err = cli("import", fmt, str(capture), "--out", str(out))
        assert code == 0, err
        assert f"{len(intact)} x 361 beams" in stdout
        back = load(out)
        assert back.meta["source"]["format"] == "lms200"
        np.testing.assert_array_equal(back.t, ds.t[intact])


@pytest.mark.parametrize("content", [b"", b"hello, this is not a capture\n" * 40])
def test_cli_bad_input_is_one_line_and_no_output(
    content: bytes,
    tmp_path: Path,
    cli: Cli,
) -> None:
    src = tmp_path / "bad.lms"
    src.write_bytes(content)
    assert_bad_input_is_one_line(cli, "lms200", src, tmp_path)


@pytest.mark.parametrize("crc", ["numpy", "numba"])
def test_search_progress_advances_with_the_bytes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, crc: str
) -> None:
    """The bar of the telegram search counts the capture's bytes, step by step as the CRCs
    are checked, and the steps change nothing: same scans, same report as one step."""
    ds = _dataset(scans=400, beams=181, seed=3)
    capture, _, _ = write(
        ds, tmp_path, noise_bytes=6.0, bit_error_rate=2e-5, truncate_last=True, seed=3
    )
    monkeypatch.setattr(lms200, "SEARCH_FRAMES", 10**9)
    whole = _read(capture, crc=crc)
    made: dict[str, Recording] = {}
    monkeypatch.setattr(lms200, "SEARCH_FRAMES", 64)
    monkeypatch.setattr(lms200, "task", _recorded_task(made))
    stepped = _read(capture, crc=crc)
    bar = made[f"searching {capture.name}"]
    (search,) = bar.tasks
    size = capture.stat().st_size
    assert search.total == size and search.completed == size
    assert len(bar.steps) >= 400 // 64 and all(step > 0 for step in bar.steps)
    assert max(bar.steps) < size / 3  # bytes, not one jump at the end
    np.testing.assert_array_equal(stepped.t, whole.t)
    np.testing.assert_array_equal(stepped.ranges, whole.ranges)
    assert stepped.meta["capture"] == whole.meta["capture"]
    assert stepped.meta["import_report"] == whole.meta["import_report"]


def _recorded_task(made: dict[str, Recording]) -> Callable[..., Any]:
    """`toolkit.progress.task` with a bar that records its advances (`made`, by description)."""

    @contextmanager
    def recorded(description: str, total: float) -> Iterator[tuple[Recording, TaskID]]:
        with Recording(made) as progress:
            yield progress, progress.add_task(description, total=total)

    return recorded
