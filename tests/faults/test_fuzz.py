"""Property-based fuzzing (hypothesis) of every importer and of the regions CSV: any bytes
give a dataset that passes the plausibility checks, or one ToolkitError; never another
exception, never a hang (each example has a deadline), never an implausible dataset.

The bytes are drawn both at random and as damaged copies of a real sample of the format (a
few lines or bytes cut, replaced, repeated), which reach deep into the parsers."""

from __future__ import annotations

import bz2
import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import importers
from tests.conftest import ROOT
from toolkit.errors import ToolkitError

SAMPLES = ROOT / "datasets"
FUZZ = settings(
    max_examples=40,
    deadline=10_000,  # ms: generous on a loaded machine; a hang still fails
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    derandomize=True,
)


def _head(data: bytes, lines: int) -> bytes:
    return b"".join(data.splitlines(keepends=True)[:lines])


def _seed(fmt: str) -> bytes:
    """The start of a real sample of the format (uncompressed)."""
    if fmt == "carmen":
        return _head(gzip.decompress((SAMPLES / "corridor-carmen" / "sim.log.gz").read_bytes()), 40)
    if fmt == "aria":
        return _head(gzip.decompress((SAMPLES / "corridor-aria" / "log.2d.gz").read_bytes()), 60)
    if fmt == "rawseeds":
        laser = next((SAMPLES / "building-rawseeds").glob("*SICK_FRONT.csv.bz2"))
        return _head(bz2.decompress(laser.read_bytes()), 30)
    if fmt == "lms200":
        return (SAMPLES / "corridor-lms200" / "capture.lms").read_bytes()[:6000]
    if fmt == "table":
        text = _head(gzip.decompress((SAMPLES / "corridor-carmen" / "sim.log.gz").read_bytes()), 60)
        rows = [ln.split()[1:] for ln in text.splitlines() if ln.startswith(b"FLASER")]
        return b"".join(b"%d," % i + b",".join(r[1:40]) + b"\n" for i, r in enumerate(rows))
    raise ValueError(fmt)


@st.composite
def damaged(draw: st.DrawFn, seed: bytes) -> bytes:
    """`seed` with a few edits: cut, flip, insert or repeat a run of bytes."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 4))):
        if not data:
            break
        at = draw(st.integers(0, len(data) - 1))
        span = draw(st.integers(1, 64))
        kind = draw(st.sampled_from(["cut", "flip", "insert", "repeat", "truncate"]))
        if kind == "cut":
            del data[at : at + span]
        elif kind == "flip":
            data[at : at + span] = draw(st.binary(min_size=span, max_size=span))
        elif kind == "insert":
            data[at:at] = draw(st.sampled_from([b"nan", b"-inf", b"1e308", b"7.9e165", b"-1",
                                                b"\n", b"\r", b"\x00", b"\xff\xfe", b" ", b","]))  # fmt: skip
        elif kind == "repeat":
            data[at:at] = data[at : at + span] * draw(st.integers(1, 20))
        else:
            del data[at:]
    return bytes(data)


def inputs(fmt: str) -> st.SearchStrategy[bytes]:
    return st.one_of(st.binary(max_size=4000), damaged(_seed(fmt)))


def plausible(path: Path) -> None:
    import toolkit

    ds = toolkit.load(path)
    assert np.isfinite(ds.t).all()
    assert (np.diff(ds.t) >= -1e-3).all()
    r = ds.ranges[np.isfinite(ds.ranges)]
    assert ((r >= 0) & (r <= 1e6)).all()
    assert ds.ranges.shape[1] == ds.laser.beams >= 1
    for frame in (ds.odometry, ds.groundtruth, *ds.poses.values()):
        if frame is not None and len(frame):
            v = frame[["t", "x", "y", "theta"]].to_numpy()
            assert np.isfinite(v).all() and (np.abs(v[:, 1:3]) <= 1e6).all()


def import_bytes(fmt: str, data: bytes, tmp: Path, compress: str = "") -> None:
    """Import `data` as a log of `fmt`: a dataset that passes `plausible`, or a ToolkitError."""
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    if fmt == "rawseeds":
        source = tmp / "Fuzz_2009-02-25a"
        source.mkdir()
        (source / "Fuzz_2009-02-25a-SICK_FRONT.csv").write_bytes(data)
    else:
        name = {"carmen": "log.log", "aria": "log.2d", "lms200": "capture.lms", "table": "log.csv"}
        source = tmp / name.get(fmt, "log")
        if compress == "gz":
            data = gzip.compress(data)
        source.write_bytes(data)
    out = tmp / "ds"
    try:
        importers.import_log(fmt, [source], out)
    except ToolkitError as e:
        assert "\n" not in e.line()
        assert not out.exists()
        return
    plausible(out)


@pytest.mark.parametrize("fmt", ["carmen", "aria", "table", "rawseeds", "lms200", "auto"])
@pytest.mark.filterwarnings("error::pandas.errors.ParserWarning")  # a stray stderr line
def test_any_bytes_give_a_dataset_or_one_error(fmt: str, tmp_path: Path) -> None:
    seed_fmt = "carmen" if fmt == "auto" else fmt

    @FUZZ
    @given(data=inputs(seed_fmt), gz=st.sampled_from(["", "gz"]))
    def check(data: bytes, gz: str) -> None:
        import_bytes(fmt, data, tmp_path / "case", "" if fmt in ("rawseeds", "lms200") else gz)

    check()


def test_rosbag_bytes(tmp_path: Path) -> None:
    """A small real bag, damaged: a dataset or one error."""
    source = tmp_path / "seed"
    from toolkit.dataset import Dataset, LaserGeometry

    t = np.arange(20) * 0.1
    seed_ds = Dataset(t, np.full((20, 5), 2.0, np.float32), LaserGeometry(5, -1.0, 0.5, 10.0))
    bag = importers.get("rosbag").write(seed_ds, source)[0]
    seed = bag.read_bytes()

    @FUZZ
    @given(data=st.one_of(st.binary(max_size=2000), damaged(seed)))
    def check(data: bytes) -> None:
        case = tmp_path / "case"
        if case.exists():
            shutil.rmtree(case)
        case.mkdir()
        (case / "log.bag").write_bytes(data)
        try:
            importers.import_log("rosbag", [case / "log.bag"], case / "ds")
        except ToolkitError as e:
            assert "\n" not in e.line()
            return
        plausible(case / "ds")

    check()


def test_regions_csv(tmp_path: Path) -> None:
    """Any bytes as a regions CSV: spans, or one FormatError."""
    from toolkit.features.regions import read_regions

    t = np.arange(200) * 0.1 + 1.7e9
    seed = b"feature,start,end\ndoor,1700000001.0,1700000002.0\nwall,1700000010,1700000011.5\n"
    path = tmp_path / "regions.csv"

    @FUZZ
    @given(data=st.one_of(st.binary(max_size=500), damaged(seed)))
    def check(data: bytes) -> None:
        path.write_bytes(data)
        try:
            spans = read_regions(path, t)
        except ToolkitError as e:
            assert "\n" not in e.line()
            return
        assert isinstance(spans, list)

    check()
