"""`rosbag` importer and writer: round trips through rosbags-written bags (ROS1, ROS2 sqlite3,
mcap), the two real CCNY bags (one rosbags rejects, one pre-2010), topic choice, tf odometry,
range filtering, damaged bags."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import importers
from importers.rosbag import ros1raw
from importers.rosbag.importer import RosbagOptions, RosbagWriteOptions
from importers.rosbag.writer import TFMESSAGE, _Messages, _typestore
from tests.importers.checks import DAMAGES, damaged
from toolkit.dataset import Dataset, LaserGeometry
from toolkit.errors import FormatError, ToolkitError

CCNY = "ccny_scan_tools_bags"
ROSBAG = importers.get("rosbag")


def _dataset(scans: int = 60, beams: int = 181, seed: int = 0) -> Dataset:
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.2, 25.0, (scans, beams)).astype(np.float32)
    ranges[rng.random((scans, beams)) < 0.05] = np.nan
    t = 1_300_000_000.0 + np.arange(scans) * 0.1 + rng.uniform(0, 0.01, scans)
    odo = pd.DataFrame(
        {
            "t": t,
            "x": np.cumsum(rng.uniform(0, 0.1, scans)),
            "y": np.cumsum(rng.normal(0, 0.02, scans)),
            "theta": np.angle(np.exp(1j * np.cumsum(rng.normal(0, 0.2, scans)))),
        }
    )
    gt = odo.assign(x=odo.x + 0.5, theta=-odo.theta)
    laser = LaserGeometry.sick_180(beams, range_max=30.0, x=0.08, y=-0.01, z=0.45, yaw=0.1)
    return Dataset(t, ranges, laser, odometry=odo, groundtruth=gt)


@pytest.mark.parametrize("version", ["ros1", "ros2", "mcap"])
def test_round_trip_through_each_bag_kind(tmp_path: Path, version: str) -> None:
    ds = _dataset()
    (bag,) = ROSBAG.write(ds, tmp_path, RosbagWriteOptions(version=version))
    assert ROSBAG.sniff(bag)
    assert importers.detect([bag]).name == "rosbag"
    back = ROSBAG.read([bag], RosbagOptions())
    assert ds.odometry is not None and ds.groundtruth is not None
    np.testing.assert_array_equal(back.ranges, ds.ranges)  # NaN (written as inf) back to NaN
    np.testing.assert_allclose(back.t, ds.t, rtol=0, atol=1e-9)
    assert back.odometry is not None and back.groundtruth is not None
    np.testing.assert_allclose(back.odometry.to_numpy(), ds.odometry.to_numpy(), atol=1e-9)
    np.testing.assert_allclose(back.groundtruth.to_numpy(), ds.groundtruth.to_numpy(), atol=1e-9)
    for name in ("angle_min", "angle_increment", "range_max", "x", "y", "z", "yaw"):
        assert getattr(back.laser, name) == pytest.approx(getattr(ds.laser, name), abs=1e-6)
    meta = back.meta["rosbag"]
    assert meta["encoding"] == ("ros1" if version == "ros1" else "cdr")
    assert (meta["odometry"], meta["groundtruth"]) == ("/odom", "/ground_truth")
    assert meta["invalid_readings"] == int(np.isnan(ds.ranges).sum())


@pytest.mark.parametrize("version", ["ros1", "mcap"])
def test_a_jittered_host_clock_moves_the_scans_stamps_alone(tmp_path: Path, version: str) -> None:
    """`clock_jitter`: the scans' header stamps spread around their times by about that sd and
    stay in order; the ranges, the odometry and the ground truth are the ones written without
    it, and the same seed writes the same stamps."""
    ds = _dataset(scans=400)
    options = RosbagWriteOptions(version=version, clock_jitter=0.015, seed=3)
    back, again = (
        ROSBAG.read(ROSBAG.write(ds, tmp_path / name, options), RosbagOptions())
        for name in ("one", "two")
    )
    assert np.all(np.diff(back.t) >= 0) and 0.012 < np.std(back.t - ds.t) < 0.018
    np.testing.assert_array_equal(back.t, again.t)
    np.testing.assert_array_equal(back.ranges, ds.ranges)
    assert back.odometry is not None and ds.odometry is not None
    np.testing.assert_allclose(back.odometry.to_numpy(), ds.odometry.to_numpy(), atol=1e-9)
    with pytest.raises(ToolkitError, match="clock_jitter"):
        ROSBAG.write(ds, tmp_path / "bad", RosbagWriteOptions(clock_jitter=-0.01))


@pytest.mark.parametrize("version", ["ros1", "ros2"])
def test_single_scan_bag(tmp_path: Path, version: str) -> None:
    ranges = np.array([[1.0, 0.0, np.nan, 3.5]], np.float32)
    ds = Dataset(np.array([7.25]), ranges, LaserGeometry(4, -0.3, 0.2, 4.0))
    (bag,) = ROSBAG.write(ds, tmp_path, RosbagWriteOptions(version=version))
    back = ROSBAG.read([bag], RosbagOptions())
    np.testing.assert_array_equal(back.ranges, [[1.0, np.nan, np.nan, 3.5]])  # 0 = invalid
    assert back.t.tolist() == [7.25] and back.odometry is None


def test_raw_and_rosbags_decoders_agree(tmp_path: Path) -> None:
    (bag,) = ROSBAG.write(_dataset(beams=361), tmp_path, RosbagWriteOptions(version="mcap"))
    raw = ROSBAG.read([bag], RosbagOptions())
    slow = ROSBAG.read([bag], RosbagOptions(decode="rosbags"))
    np.testing.assert_array_equal(raw.ranges, slow.ranges)
    np.testing.assert_array_equal(raw.t, slow.t)


# ---------------------------------------------------------------- real bags


@pytest.mark.real
def test_ccny_matcher_bag_recovered_from_its_chunks(real: Path) -> None:
    path = real / CCNY / "laser_scan_matcher" / "demo.bag"
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    with pytest.raises(AssertionError), AnyReader([path], default_typestore=store):
        pass  # the reason the recovery reader exists
    ds = ROSBAG.read([path], RosbagOptions())
    assert ds.ranges.shape == (360, 681)
    meta = ds.meta["rosbag"]
    assert meta["reader"] == "recovery (ROS1 v2.0)"
    assert any("index was ignored" in n for n in ds.report.notes)
    # SOURCE.md quotes the bag (receive) times; header stamps are ~0.1 s earlier
    assert meta["bag_time"] == pytest.approx([1282836371.07, 1282836406.88], abs=0.006)
    assert ds.t[0] == pytest.approx(1282836370.97, abs=0.01)
    assert np.all(np.diff(ds.t) > 0.05) and ds.t[-1] < meta["bag_time"][1]
    assert ds.laser.angle_min == pytest.approx(-2.08621, abs=1e-5)
    assert ds.laser.angle_increment == pytest.approx(0.00613592, abs=1e-8)
    assert ds.laser.fov == pytest.approx(2 * 2.08621, abs=1e-4)
    assert (ds.laser.range_min, ds.laser.range_max) == pytest.approx((0.02, 5.6))
    assert float(np.nanmax(ds.ranges)) == pytest.approx(5.468, abs=1e-4)
    assert float(np.nanmin(ds.ranges)) >= 0.02  # the zeros (invalid) became NaN
    assert meta["invalid_readings"] == int(np.isnan(ds.ranges).sum()) > 0
    assert ds.odometry is None and ds.report.records_read == ds.report.records_kept == 360


@pytest.mark.real
def test_pre_2010_rosrecord_bag(real: Path) -> None:
    ds = ROSBAG.read([real / CCNY / "laser_scan_sparsifier" / "demo.bag"], RosbagOptions())
    assert ds.ranges.shape == (123, 512)
    assert ds.meta["rosbag"]["scan_topic"] == "scan"
    assert ds.meta["rosbag"]["bag_time"] == pytest.approx([1275168820.02, 1275168832.18], abs=0.006)
    assert ds.laser.angle_min == pytest.approx(-1.5708, abs=1e-4)
    assert ds.laser.angle_increment == pytest.approx(0.00614, abs=1e-5)
    assert ds.laser.range_max == pytest.approx(5.6)


@pytest.mark.real
def test_cli_imports_the_real_bag_with_auto(real: Path, tmp_path: Path) -> None:
    path = real / CCNY / "laser_scan_matcher" / "demo.bag"
    done = _cli("import", "auto", str(path), "--out", str(tmp_path / "d"), "-q")
    assert done.returncode == 0, done.stderr
    import toolkit

    assert toolkit.load(tmp_path / "d").ranges.shape == (360, 681)


# ---------------------------------------------------------------- bags built with rosbags


def _laserscan(msgs: _Messages, t: float, beams: int, frame: str = "laser", **kw: object) -> object:
    fields: dict[str, object] = {
        "angle_min": -1.0,
        "angle_max": 1.0,
        "angle_increment": 2.0 / max(beams - 1, 1),
        "time_increment": 0.0,
        "scan_time": 0.1,
        "range_min": 0.1,
        "range_max": 10.0,
        "ranges": np.full(beams, 2.0, np.float32),
        "intensities": np.zeros(0, np.float32),
    }
    fields.update(kw)
    return msgs.types["sensor_msgs/msg/LaserScan"](header=msgs.header(t, frame), **fields)


def _transform(msgs: _Messages, t: float, parent: str, child: str, x: float, yaw: float) -> object:
    ty = msgs.types
    return ty["geometry_msgs/msg/TransformStamped"](
        header=msgs.header(t, parent),
        child_frame_id=child,
        transform=ty["geometry_msgs/msg/Transform"](
            translation=ty["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.2),
            rotation=msgs.quaternion(yaw),
        ),
    )


def _ros1_bag(path: Path, messages: list[tuple[str, str, float, object]]) -> Path:
    """A ROS1 bag written by rosbags from (topic, msgtype, bag time, message)."""
    from rosbags.rosbag1 import Writer

    msgs = _Messages(_typestore(True), True)
    with Writer(path) as w:
        conns = {}
        for topic, msgtype, t, msg in messages:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=msgs.store)
            w.write(conns[topic], round(t * 1e9), msgs.serialize(msg, msgtype))
    return path


SCAN = "sensor_msgs/msg/LaserScan"


def test_two_scan_topics_need_a_choice(tmp_path: Path) -> None:
    m = _Messages(_typestore(True), True)
    items = [
        (topic, SCAN, 10 + i * 0.1, _laserscan(m, 10 + i * 0.1, 90))
        for i in range(5)
        for topic in ("/front", "/rear")
    ]
    bag = _ros1_bag(tmp_path / "two.bag", items)
    with pytest.raises(
        ToolkitError,
        match=r"2 LaserScan topics: /front \(5 msgs\), /rear \(5 msgs\); choose one with --scan-topic",
    ):
        ROSBAG.read([bag], RosbagOptions())
    ds = ROSBAG.read([bag], RosbagOptions(scan_topic="rear"))
    assert ds.meta["rosbag"]["scan_topic"] == "/rear" and ds.n_scans == 5
    with pytest.raises(ToolkitError, match=r"no LaserScan topic '/side'.*/front"):
        ROSBAG.read([bag], RosbagOptions(scan_topic="/side"))
    done = _cli("import", "rosbag", str(bag), "--out", str(tmp_path / "d"))
    assert done.returncode == 1
    assert done.stderr.strip().count("\n") == 0
    assert "/front (5 msgs), /rear (5 msgs)" in done.stderr and "--scan-topic" in done.stderr
    assert not (tmp_path / "d").exists()


def test_changing_beam_count_is_rejected_naming_the_message(tmp_path: Path) -> None:
    m = _Messages(_typestore(True), True)
    items = [
        ("/scan", SCAN, 5 + i * 0.1, _laserscan(m, 5 + i * 0.1, 100 if i < 7 else 101))
        for i in range(9)
    ]
    bag = _ros1_bag(tmp_path / "b.bag", items)
    with pytest.raises(
        FormatError, match=r"beam count changes from 100 to 101 at message 7 \(bag time 5.700\)"
    ):
        ROSBAG.read([bag], RosbagOptions())


def test_ranges_outside_limits_become_nan_and_are_counted(tmp_path: Path) -> None:
    m = _Messages(_typestore(True), True)
    ranges = np.array([0.0, 0.05, 0.1, 5.0, 9.99, 10.0, 12.0, np.inf, np.nan, 3.0], np.float32)
    items = [("/scan", SCAN, 1.0 + i, _laserscan(m, 1.0 + i, 10, ranges=ranges)) for i in range(3)]
    ds = ROSBAG.read([_ros1_bag(tmp_path / "r.bag", items)], RosbagOptions())
    expect = np.array([np.nan, np.nan, 0.1, 5.0, 9.99, np.nan, np.nan, np.nan, np.nan, 3.0])
    np.testing.assert_array_equal(ds.ranges, np.tile(expect.astype(np.float32), (3, 1)))
    assert ds.meta["rosbag"]["invalid_readings"] == 3 * 6
    assert (ds.laser.range_min, ds.laser.range_max) == (pytest.approx(0.1), 10.0)


def test_odometry_and_mounting_from_tf_and_zero_stamps(tmp_path: Path) -> None:
    m = _Messages(_typestore(True), True)
    items: list[tuple[str, str, float, object]] = [
        (
            "/tf_static",
            TFMESSAGE,
            0.5,
            m.types[TFMESSAGE](transforms=[_transform(m, 0.5, "base_link", "hokuyo", 0.15, 0.0)]),
        ),
    ]
    for i in range(6):
        t = 1.0 + i * 0.1
        items.append(("/scan", SCAN, t, _laserscan(m, 0.0, 50, frame="/hokuyo")))  # stamp 0
        tfm = m.types[TFMESSAGE](
            transforms=[
                _transform(m, t, "/odom", "base_footprint", 0.1 * i, 0.05 * i),
                _transform(m, t, "map", "odom", 9.0, 0.0),  # not odometry
            ]
        )
        items.append(("/tf", TFMESSAGE, t, tfm))
    ds = ROSBAG.read([_ros1_bag(tmp_path / "tf.bag", items)], RosbagOptions())
    assert ds.meta["time_source"] == "bag time"
    np.testing.assert_allclose(ds.t, 1.0 + np.arange(6) * 0.1)
    assert ds.meta["rosbag"]["odometry"] == "tf odom -> base_footprint"
    assert ds.odometry is not None
    np.testing.assert_allclose(ds.odometry.x, 0.1 * np.arange(6), atol=1e-12)
    np.testing.assert_allclose(ds.odometry.theta, 0.05 * np.arange(6), atol=1e-12)
    assert (ds.laser.x, ds.laser.z) == pytest.approx((0.15, 0.2))
    assert any("all zero" in n for n in ds.report.notes)


def test_a_laser_mounted_upside_down_maps_as_one_mounted_level(tmp_path: Path) -> None:
    """A bag whose base_link -> laser transform turns the laser over (a common mounting):
    its beams' angles are mirrored on import, so that each return lands where the level
    laser's does and the map holds (read as level, every scan is a mirror image)."""
    from toolkit.mapping import map_run
    from toolkit.sim import simulate

    ds = simulate("corridor", seed=0, scans=300).dataset
    level, over = (
        ROSBAG.read(
            ROSBAG.write(ds, tmp_path, RosbagWriteOptions(name=name, upside_down=turned)),
            RosbagOptions(),
        )
        for name, turned in (("level", False), ("over", True))
    )
    assert level.laser.angle_increment > 0 > over.laser.angle_increment
    assert any("upside down" in n for n in over.report.notes)
    assert not any("upside down" in n for n in level.report.notes)

    def robot_frame(d: Dataset) -> np.ndarray:
        a = d.laser.angles + d.laser.yaw
        return np.stack([d.ranges * np.cos(a) + d.laser.x, d.ranges * np.sin(a) + d.laser.y])

    np.testing.assert_allclose(robot_frame(over)[:, :, ::-1], robot_frame(level), atol=1e-5)
    ates = [
        map_run(d, tmp_path / name, outputs=("metrics.json",)).metrics["ate"]["rmse"]
        for name, d in (("level", level), ("over", over))
    ]
    assert max(ates) < 0.3


def test_two_odometry_topics_need_a_choice(tmp_path: Path) -> None:
    m = _Messages(_typestore(True), True)
    items = [("/scan", SCAN, 1.0, _laserscan(m, 1.0, 20))]
    for topic in ("/odom", "/wheel_odom"):
        items.append((topic, "nav_msgs/msg/Odometry", 1.0, m.odometry(1.0, 1, 2, 0.3, "odom", 0)))
    bag = _ros1_bag(tmp_path / "o.bag", items)
    with pytest.raises(ToolkitError, match=r"2 Odometry topics: /odom .*/wheel_odom.*--odom-topic"):
        ROSBAG.read([bag], RosbagOptions())
    ds = ROSBAG.read([bag], RosbagOptions(odom_topic="/wheel_odom"))
    assert ds.odometry is not None and ds.odometry.theta[0] == pytest.approx(0.3)


# ---------------------------------------------------------------- recovery reader


@pytest.mark.parametrize("compression", [None, "bz2", "lz4"])
def test_recovery_reader_matches_rosbags_when_the_index_is_lost(
    tmp_path: Path, compression: str | None
) -> None:
    path = _chunked_bag(tmp_path / "c.bag", compression)
    whole = ROSBAG.read([path], RosbagOptions())
    assert whole.meta["rosbag"]["reader"] == "rosbags"
    # cut the index section off: rosbags cannot open the bag, the chunks are all there
    data = path.read_bytes()
    index_pos = _index_pos(data)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[:index_pos])
    recovered = ROSBAG.read([cut], RosbagOptions())
    assert recovered.meta["rosbag"]["reader"] == "recovery (ROS1 v2.0)"
    np.testing.assert_array_equal(recovered.ranges, whole.ranges)
    np.testing.assert_array_equal(recovered.t, whole.t)
    # and a bag cut inside its last chunk keeps the chunks before it, saying so
    cut.write_bytes(data[: index_pos - 300])
    partial = ROSBAG.read([cut], RosbagOptions())
    assert 0 < partial.n_scans < 40
    np.testing.assert_array_equal(partial.ranges, whole.ranges[: partial.n_scans])
    assert any("stopped at byte" in n for n in partial.report.notes)


def test_lz4_chunks_without_the_lz4_package_are_one_clear_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    data = _chunked_bag(tmp_path / "c.bag", "lz4").read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: _index_pos(data)])
    monkeypatch.setattr(ros1raw, "lz4", None)  # as when `import lz4.frame` failed
    with pytest.raises(FormatError, match="lz4-compressed chunks need the lz4 package"):
        ROSBAG.read([cut], RosbagOptions())


def _chunked_bag(path: Path, compression: str | None) -> Path:
    """40 scans in chunks of ~20 kB, compressed or not, written by rosbags."""
    from rosbags.rosbag1 import Writer

    ds = _dataset(scans=40)
    msgs = _Messages(_typestore(True), True)
    w = Writer(path)
    if compression:
        w.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    w.chunk_threshold = 20_000
    with w:
        conn = w.add_connection("/scan", SCAN, typestore=msgs.store)
        for i, t in enumerate(ds.t.tolist()):
            ranges = np.nan_to_num(ds.ranges[i], nan=np.inf)
            scan = _laserscan(msgs, t, 181, ranges=ranges, range_max=30.0, range_min=0.0)
            w.write(conn, round(t * 1e9), msgs.serialize(scan, SCAN))
    return path


def _index_pos(data: bytes) -> int:
    """Where the bag header says the index section (connections, chunk infos) starts."""
    at = data.index(b"index_pos=") + len(b"index_pos=")
    return int.from_bytes(data[at : at + 8], "little")


# ---------------------------------------------------------------- damaged input


@pytest.fixture(scope="module")
def clean_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    root = tmp_path_factory.mktemp("bags")
    ds = _dataset(scans=12, beams=31)
    out = {}
    (ros1,) = ROSBAG.write(ds, root / "a", RosbagWriteOptions(version="ros1"))
    out["ros1"] = ros1.read_bytes()
    (mcap,) = ROSBAG.write(ds, root / "b", RosbagWriteOptions(version="mcap"))
    out["mcap"] = next(mcap.glob("*.mcap")).read_bytes()
    (ros2,) = ROSBAG.write(ds, root / "c", RosbagWriteOptions(version="ros2"))
    out["db3"] = next(ros2.glob("*.db3")).read_bytes()
    return out


@settings(
    max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    kind=st.sampled_from(["ros1", "mcap", "db3"]),
    damage=st.sampled_from(DAMAGES),
    where=st.floats(0, 1),
    bit=st.integers(0, 7),
)
def test_damaged_bags_give_a_dataset_or_one_clear_error(
    tmp_path: Path, clean_bags: dict[str, bytes], kind: str, damage: str, where: float, bit: int
) -> None:
    data = damaged(
        clean_bags[kind], damage, where, bit, b"\x00garbage\xff", b"\xff\xff\xff\x7f", insert=False
    )
    path = tmp_path / f"x{hash((damage, where, bit))}.{'bag' if kind == 'ros1' else kind}"
    path.write_bytes(data)
    try:
        ds = ROSBAG.read([path], RosbagOptions())
    except ToolkitError as e:
        assert "\n" not in e.line()
        return
    assert ds.n_scans > 0 and ds.report.records_kept == ds.n_scans
    assert np.isfinite(ds.t).all() and (np.diff(ds.t) >= 0).all()
    assert math.isfinite(ds.laser.angle_min) and math.isfinite(ds.laser.range_max)


def test_not_a_bag_is_one_clear_error(tmp_path: Path) -> None:
    bogus = tmp_path / "x.bag"
    bogus.write_text("hello\n")
    assert not ROSBAG.sniff(bogus)
    with pytest.raises(FormatError, match="not a ROS bag"):
        ROSBAG.read([bogus], RosbagOptions())
    done = _cli("import", "rosbag", str(bogus), "--out", str(tmp_path / "d"))
    assert done.returncode == 1 and done.stderr.count("\n") == 1 and "not a ROS bag" in done.stderr


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    code = "from toolkit.app.cli import main; main()"
    return subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, check=False
    )
