"""rosbag import speed: LaserScan messages per second, bulk raw decoding vs rosbags' deserialiser.

Bags of 20,000 LaserScan messages (181 and 720 beams; quick: 2,000) are written with the
toolkit's writer as ROS1, ROS2 sqlite3 and ROS2 mcap, then read three ways, median of 3:
`iterate` only walks the messages with rosbags (the floor), `raw` is the importer's default
(LaserScan bytes decoded in bulk with numpy), `rosbags` the importer with rosbags'
per-message deserialiser (-O decode=rosbags).
"""

from __future__ import annotations

import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

import importers
from importers.rosbag.importer import RosbagOptions, RosbagWriteOptions
from importers.rosbag.source import open_bag
from toolkit.dataset import Dataset, LaserGeometry

REPEATS = 3


def _dataset(scans: int, beams: int) -> Dataset:
    rng = np.random.default_rng(beams)
    ranges = rng.uniform(0.1, 20.0, (scans, beams)).astype(np.float32)
    ranges[rng.random((scans, beams)) < 0.05] = np.nan
    t = 1.6e9 + np.arange(scans) * 0.025
    fov = np.deg2rad(270.0)
    laser = LaserGeometry(beams, -fov / 2, fov / (beams - 1), 30.0)
    return Dataset(t, ranges, laser)


def _iterate(bag: Path) -> int:
    with open_bag([bag]) as source:
        return sum(1 for _ in source.messages(["/scan"]))


def _median_seconds(fn: object, repeats: int = REPEATS) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()  # type: ignore[operator]
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    rosbag = importers.get("rosbag")
    scans = 2_000 if quick else 20_000
    rows: list[dict[str, object]] = []
    work = Path(tempfile.mkdtemp(prefix="bench-rosbag-", dir=out))
    try:
        for beams in (181, 720):
            ds = _dataset(scans, beams)
            for version in ("ros1", "ros2", "mcap"):
                start = time.perf_counter()
                (bag,) = rosbag.write(
                    ds, work / f"{version}-{beams}", RosbagWriteOptions(version=version)
                )
                write_s = time.perf_counter() - start
                size = sum(f.stat().st_size for f in ([bag] if bag.is_file() else bag.iterdir()))
                figures = {
                    "iterate": _median_seconds(lambda bag=bag: _iterate(bag)),
                    "raw": _median_seconds(lambda bag=bag: rosbag.read([bag], RosbagOptions())),
                    "rosbags": _median_seconds(
                        lambda bag=bag: rosbag.read([bag], RosbagOptions(decode="rosbags"))
                    ),
                }
                check = rosbag.read([bag], RosbagOptions())
                assert check.ranges.shape == (scans, beams)
                for how, seconds in figures.items():
                    rows.append(
                        {
                            "name": f"{version} {beams} beams {how}",
                            "bag": version,
                            "beams": beams,
                            "messages": scans,
                            "read": how,
                            "seconds": round(seconds, 4),
                            "msgs_per_s": round(scans / seconds),
                            "vs_rosbags": round(figures["rosbags"] / seconds, 2),
                            "bag_mb": round(size / 1e6, 1),
                            "write_s": round(write_s, 2),
                        }
                    )
                shutil.rmtree(work / f"{version}-{beams}", ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return rows
