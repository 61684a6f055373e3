"""`toolkit import --each [--scheduler]`: a fleet's directory tree of real CARMEN logs, one
dataset each (FLEET/dataset=<name>, hive-partitioned); a damaged log is reported by name without stopping the others; a re-run skips
what is complete and re-imports what changed; a LocalCluster writes the same datasets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import Cli
from toolkit.app.fleet import dataset_name, find_logs, partition_dir
from toolkit.dataset import load

pytestmark = [pytest.mark.real, pytest.mark.xdist_group("dask")]

LOGS = ("orebro-corrected.log.gz", "fhw-corrected.log.gz")


@pytest.fixture
def fleet(real: Path, tmp_path: Path) -> Path:
    """robotA/orebro, robotB/fhw (links to the real logs), robotB/broken.log.gz (a real log's
    first 3 kB then garbage: its gzip stream breaks) and a notes file no format claims."""
    carmen = real / "carmen_radish_corrected"
    root = tmp_path / "fleet"
    (root / "robotA").mkdir(parents=True)
    (root / "robotB").mkdir()
    (root / "robotA" / LOGS[0]).symlink_to(carmen / LOGS[0])
    (root / "robotB" / LOGS[1]).symlink_to(carmen / LOGS[1])
    head = (carmen / "edmonton-corrected.log.gz").read_bytes()[:3000]
    noise = np.random.default_rng(0).integers(0, 256, 20_000, dtype=np.uint8).tobytes()
    (root / "robotB" / "broken.log.gz").write_bytes(head + noise)
    (root / "notes.txt").write_text("robot A had a flat tyre on Tuesday\n")
    return root


def test_dataset_names_mirror_the_tree(fleet: Path) -> None:
    assert dataset_name(fleet / "robotA" / LOGS[0], fleet) == Path("robotA/orebro-corrected")
    assert dataset_name(Path("/x/run.7.log.bz2"), None) == Path("run.7")
    assert partition_dir(Path("robotA/orebro-corrected")) == "dataset=robotA%2Forebro-corrected"
    found = find_logs("carmen", [fleet])
    assert [name for _, name in found] == [
        Path("robotA/orebro-corrected"),
        Path("robotB/broken"),
        Path("robotB/fhw-corrected"),
    ]


def _same_dataset(a: Path, b: Path) -> None:
    x, y = load(a), load(b)
    assert np.array_equal(x.t, y.t)
    assert np.array_equal(x.ranges, y.ranges, equal_nan=True)
    assert x.odometry is not None and y.odometry is not None
    assert x.odometry.equals(y.odometry)


def test_each_reports_the_damaged_log_and_writes_the_others(
    fleet: Path, real: Path, tmp_path: Path, cli: Cli
) -> None:
    out = tmp_path / "out"
    code, stdout, err = cli("import", "carmen", fleet, "--each", "--out", out)
    assert code == 1
    failures = err.strip().splitlines()
    assert len(failures) == 1 and "Traceback" not in err
    assert failures[0].startswith(f"failed: {fleet / 'robotB' / 'broken.log.gz'}: ")
    assert "2 written, 0 skipped (complete), 1 failed, of 3 logs" in stdout
    assert sorted(p.name for p in out.iterdir()) == [
        "dataset=robotA%2Forebro-corrected",
        "dataset=robotB%2Ffhw-corrected",
    ]
    code, _, err = cli("import", "carmen", real / "carmen_radish_corrected" / LOGS[0],
                       "--out", tmp_path / "alone", "-q")  # fmt: skip
    assert code == 0, err
    _same_dataset(out / "dataset=robotA%2Forebro-corrected", tmp_path / "alone")
    assert load(out / "dataset=robotB%2Ffhw-corrected").n_scans > 100

    # re-run: complete datasets are skipped; a changed source is imported again
    (fleet / "robotB" / "broken.log.gz").unlink()
    code, stdout, err = cli("import", "carmen", fleet, "--each", "--out", out)
    assert (code, err) == (0, "")
    assert "0 written, 2 skipped (complete), 0 failed, of 2 logs" in stdout
    link = fleet / "robotA" / LOGS[0]
    link.unlink()
    link.symlink_to(real / "carmen_radish_corrected" / "belgioioso-corrected.log.gz")
    code, stdout, _ = cli("import", "carmen", fleet, "--each", "--out", out)
    assert "1 written, 1 skipped (complete), 0 failed, of 2 logs" in stdout
    again = load(out / "dataset=robotA%2Forebro-corrected")
    assert again.n_scans != load(tmp_path / "alone").n_scans


@pytest.mark.slow
def test_local_cluster_writes_the_same_datasets(fleet: Path, tmp_path: Path, cli: Cli) -> None:
    one, two = tmp_path / "one", tmp_path / "two"
    pattern = str(fleet / "robot*" / "*.log.gz")  # quoted glob: the toolkit expands it
    code, _, err = cli("import", "carmen", pattern, "--each", "--out", one, "-q")
    assert code == 1 and "broken.log.gz" in err
    code, stdout, err = cli(
        "import", "carmen", pattern, "--each", "--out", two, "--scheduler", "local:2"
    )
    assert code == 1
    assert len(err.strip().splitlines()) == 1 and "broken.log.gz" in err
    assert "2 written, 0 skipped (complete), 1 failed, of 3 logs" in stdout
    for name in ("dataset=orebro-corrected", "dataset=fhw-corrected"):
        _same_dataset(one / name, two / name)
