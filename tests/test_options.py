"""Options: every format's keys checked, `import auto` takes laser logs only, and a help that
reads like its peers' (flags as flags, types in words, --version, formats with read/write)."""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import subprocess
import sys
import typing
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import importers
from importers.base import FormatOptions, looks_like_tum
from importers.carmen import CarmenOptions
from tests.conftest import ROOT, Cli
from toolkit.app.cli import app
from toolkit.errors import ToolkitError
from toolkit.typed import choices, field_types

CARMEN_LOG = ROOT / "datasets" / "corridor-carmen"


def one_line_error(code: int, err: str, *needles: str) -> str:
    """Exit 1 and one line on stderr holding every needle; the line."""
    lines = err.strip().splitlines()
    assert code == 1 and len(lines) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------------ every format's keys


def test_a_typo_of_poses_fails_naming_the_known_keys(tmp_path: Path, cli: Cli) -> None:
    """`-O pose=groundtruth` (for poses) used to import without truth and say nothing."""
    code, _, err = cli(
        "import", "carmen", CARMEN_LOG, "--out", tmp_path / "d", "-O", "pose=groundtruth"
    )
    one_line_error(code, err, "unknown option 'pose' for carmen; known: poses, range_max")
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("fmt", importers.names())
def test_every_format_refuses_an_unknown_key(fmt: str, tmp_path: Path, cli: Cli) -> None:
    source = tmp_path / "log"
    source.write_text("anything\n")
    code, _, err = cli("import", fmt, source, "--out", tmp_path / "d", "-O", "bogus=1")
    known = [f.name for f in dataclasses.fields(importers.get(fmt).Options)]
    line = one_line_error(code, err, f"unknown option 'bogus' for {fmt}; known: ")
    assert line.endswith(", ".join(known))
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize(
    ("flag", "fmt"),
    [("--scan-topic", "carmen"), ("--odom-topic", "aria"), ("--laser", "lms200"),
     ("--rate", "rosbag"), ("--rate", "rawseeds")],
)  # fmt: skip
def test_a_flag_the_format_does_not_take_is_an_error(
    flag: str, fmt: str, tmp_path: Path, cli: Cli
) -> None:
    """`--scan-topic` on a CARMEN import used to be ignored."""
    source = tmp_path / "log"
    source.write_text("anything\n")
    code, _, err = cli("import", fmt, source, "--out", tmp_path / "d", flag, "5")
    one_line_error(code, err, f"{flag} does not apply to {fmt}; its options: ")


@pytest.mark.parametrize(
    ("option", "needle"),
    [
        ("range_max=far", "range_max=far for carmen: expected none|number"),
        ("poses=truth", "poses=truth for carmen: expected odometry|groundtruth"),
        ("laser_x=forty", "laser_x=forty for carmen: expected number"),
    ],
)
def test_a_value_of_the_wrong_type_names_the_type(
    option: str, needle: str, tmp_path: Path, cli: Cli
) -> None:
    code, _, err = cli("import", "carmen", CARMEN_LOG, "--out", tmp_path / "d", "-O", option)
    one_line_error(code, err, needle)


def test_an_option_given_twice_is_an_error(tmp_path: Path, cli: Cli) -> None:
    code, _, err = cli(
        "import", "carmen", CARMEN_LOG, "--out", tmp_path / "d",
        "-O", "poses=groundtruth", "-O", "poses=odometry",
    )  # fmt: skip
    one_line_error(code, err, "-O poses= given twice")


def test_options_are_parsed_once_into_the_typed_object() -> None:
    given = importers.ImportOptions(rate=5.0, extra={"poses": "GroundTruth", "range_max": "30"})
    typed = importers.read_options(importers.get("carmen"), given)
    assert typed == CarmenOptions(poses="groundtruth", range_max=30.0, rate=5.0)
    assert isinstance(typed.range_max, float) and typed.laser_x is None
    # built in Python, held to the same types and choices
    with pytest.raises(ToolkitError, match="poses=truth for carmen"):
        CarmenOptions(poses="truth")  # type: ignore[arg-type]
    with pytest.raises(ToolkitError, match=r"rate=-1\.0 for carmen: must be positive"):
        CarmenOptions(rate=-1.0)
    with pytest.raises(ToolkitError, match="-O rate= both given"):
        importers.read_options(
            importers.get("carmen"), importers.ImportOptions(rate=5.0, extra={"rate": "4"})
        )


def test_a_typed_option_changes_the_import(tmp_path: Path, cli: Cli) -> None:
    """The parsed option reaches the reader: poses=groundtruth stores the laser lines' robot
    poses (here the drifting odometry) as the ground truth, replacing TRUEPOS."""
    from toolkit.dataset import load

    plain, truth = tmp_path / "plain", tmp_path / "truth"
    assert cli("import", "carmen", CARMEN_LOG, "--out", plain, "-q")[0] == 0
    assert cli("import", "carmen", CARMEN_LOG, "--out", truth, "-q", "-O", "poses=GROUNDTRUTH")[0] == 0  # fmt: skip
    a, b = load(plain), load(truth)
    assert a.groundtruth is not None and b.groundtruth is not None and a.odometry is not None
    assert not a.groundtruth[["x", "y"]].equals(b.groundtruth[["x", "y"]])
    end = b.groundtruth[["x", "y"]].to_numpy()[-1] - a.odometry[["x", "y"]].to_numpy()[-1]
    assert abs(end).max() < 0.05  # the laser lines' robot pose is the odometry


def test_writer_options_are_checked_before_any_work(tmp_path: Path, cli: Cli) -> None:
    out = tmp_path / "sim"
    base = ["simulate", "corridor", "--out", out, "--scans", "20"]
    code, _, err = cli(*base, "-f", "carmen", "-O", "hots=x")
    one_line_error(code, err, "unknown option 'hots' for the carmen writer; known: name, host")
    code, _, err = cli(*base, "-f", "aria", "-O", "version=5")
    one_line_error(code, err, "version=5 for the aria writer: expected 2|3|4")
    code, _, err = cli(*base, "-f", "lms200", "-O", "truncate_last=maybe")
    one_line_error(code, err, "truncate_last=maybe for the lms200 writer: expected true|false")
    assert not out.exists()
    code, _, err = cli(*base, "-f", "aria", "-O", "version=2", "-O", "points=false", "-p", "beams=91")  # fmt: skip
    assert code == 0, err
    text = next(out.glob("*.2d")).read_text()
    assert "\ntime:" in text and "sick1:" in text and "scan1:" not in text


# ------------------------------------------------------------------ auto takes logs only


@pytest.fixture(scope="module")
def outputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The toolkit's own outputs of a short simulated log: dataset, map run, labels."""
    root = tmp_path_factory.mktemp("outputs")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}

    def run(*args: object) -> None:
        done = subprocess.run(
            [sys.executable, "-m", "toolkit", *map(str, args)],
            capture_output=True, text=True, env=env, timeout=600,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr

    ds, out = root / "ds", root / "run"
    run("simulate", "corridor", "--scans", "300", "-f", "dataset", "--out", ds)
    run("map", ds, "--out", out, "--method", "odometry", "-q")
    run("label", ds, "--out", out, "--regions", ds / "regions.csv")
    files = {p.name: p for p in [*ds.iterdir(), *out.iterdir()]}
    return files


@pytest.mark.parametrize(
    ("name", "what"),
    [
        ("trajectory.tum", "a TUM trajectory (t x y z qx qy qz qw)"),
        ("scans.parquet", "a Parquet file"),
        ("labels.parquet", "a Parquet file"),
        ("metrics.json", "a JSON file"),
        ("cloud.ply", "a PLY point cloud"),
    ],
)
def test_auto_refuses_the_toolkits_own_outputs(
    outputs: dict[str, Path], name: str, what: str, tmp_path: Path, cli: Cli
) -> None:
    """`import auto trajectory.tum` used to import the trajectory as a 4-beam laser log."""
    code, _, err = cli("import", "auto", outputs[name], "--out", tmp_path / "d")
    one_line_error(code, err, str(outputs[name]), what, "not a laser log")
    assert not (tmp_path / "d").exists()


def test_auto_refuses_a_dataset_directory(
    outputs: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    dataset = outputs["scans.parquet"].parent
    code, _, err = cli("import", "auto", dataset, "--out", tmp_path / "d")
    one_line_error(code, err, "a dataset directory (already imported", "not a laser log")


def test_auto_refuses_a_tum_file_whatever_its_name(
    outputs: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    poses = tmp_path / "poses.txt"
    shutil.copy(outputs["trajectory.tum"], poses)
    assert looks_like_tum(poses.read_bytes())
    code, _, err = cli("import", "auto", poses, "--out", tmp_path / "d")
    one_line_error(code, err, "a TUM trajectory")
    # a table of 8 columns that is no trajectory is still a table
    table = tmp_path / "scans.txt"
    table.write_text("".join(f"{i} 1 2 3 4 5 6 7\n" for i in range(10)))
    assert not looks_like_tum(table.read_bytes()) and importers.detect([table]).name == "table"


def test_each_skips_the_toolkits_outputs_beside_a_log(
    outputs: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    """`--each` over a folder holding a log and a run's outputs imports the log only."""
    folder = tmp_path / "logs"
    folder.mkdir()
    shutil.copy(next(CARMEN_LOG.glob("*.log*")), folder)
    for name in ("trajectory.tum", "groundtruth.tum", "metrics.json", "cloud.ply"):
        shutil.copy(outputs[name], folder / name)
    code, out, err = cli("import", "auto", folder, "--each", "--out", tmp_path / "fleet")
    assert code == 0, err
    assert "1 written" in out and "of 1 logs" in out
    assert len(list((tmp_path / "fleet").glob("dataset=*"))) == 1


# ------------------------------------------------------------------ help like its peers


def _help(*args: str, columns: int) -> str:
    env = {**os.environ, "COLUMNS": str(columns), "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-m", "toolkit", *args, "--help"],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.mark.parametrize("columns", [80, 120])
def test_help_shows_flags_as_flags_and_types_in_words(columns: int) -> None:
    commands = [c.name or "" for c in app.registered_commands]
    for args in [(), *((c,) for c in commands)]:
        text = _help(*args, columns=columns)
        assert not re.search(r"<(bool|str|int|float|path|list\[)", text, re.I), (args, text)
        assert "│" not in text  # plain, no boxes that break when copied or piped
        assert max(len(line) for line in text.splitlines()) <= columns
        assert " -o," not in text and " -o " not in text  # -O only: format options
    flags = _help("map", columns=columns)
    assert re.search(r"^\s+--force\s+replace an existing run", flags, re.M)
    assert re.search(r"^\s+--out DIR\s", flags, re.M)
    # no hard line break of the docstring shows through: the paragraph is rewrapped
    assert "(ROS map_server)" in flags and "trajectory.tum (evo)," in flags


def test_force_is_a_flag_and_takes_no_value(
    outputs: dict[str, Path], tmp_path: Path, cli: Cli
) -> None:
    dataset = outputs["scans.parquet"].parent
    code, _, err = cli("map", dataset, "--out", tmp_path / "run", "--force", "true")
    one_line_error(code, err, "true: no such file or directory")  # a second DATASET
    code, _, err = cli("map", dataset, "--out", tmp_path / "run", "--method", "odometry", "-q")
    assert code == 0, err
    code, _, err = cli("map", dataset, "--out", tmp_path / "run", "--method", "odometry", "--force", "-q")  # fmt: skip
    assert code == 0, err


def test_version(cli: Cli) -> None:
    import tomllib

    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    for flag in ("--version", "-V"):
        code, out, err = cli(flag)
        assert code == 0, err
        assert out.strip() == f"toolkit {version}"


def test_formats_lists_read_write_and_every_option(cli: Cli) -> None:
    code, out, err = cli("formats")
    assert code == 0, err
    table = out.split("\n\n")[0].splitlines()
    assert table[0].split() == ["FORMAT", "READ", "WRITE", "SOURCES"]
    rows = {line.split()[0]: line.split()[1:3] for line in table[1:] if line[:1] != " "}
    for name in importers.names():
        imp = importers.get(name)
        assert rows[name] == ["yes", "yes" if imp.writes else "no"]
        for spec in imp.Options.specs():
            assert f"  {spec.name}={spec.type}  (default {spec.default}" in out
        for spec in imp.WriteOptions.specs() if imp.WriteOptions else []:
            assert f"  {spec.name}={spec.type}  (default {spec.default})" in out
    code, out, _ = cli("formats", "carmen")
    assert code == 0 and "poses=odometry|groundtruth  (default odometry)" in out
    assert "rosbag" not in out


def test_the_docs_page_lists_what_toolkit_formats_prints(
    monkeypatch: pytest.MonkeyPatch, cli: Cli
) -> None:
    """docs/formats.md ends with `COLUMNS=100 toolkit formats`; regenerate it when this fails."""
    monkeypatch.setenv("COLUMNS", "100")
    code, out, err = cli("formats")
    assert code == 0, err
    page = (ROOT / "docs" / "formats.md").read_text()
    block = page.split("<!-- generated: COLUMNS=100 toolkit formats")[1].split("```\n")[1]
    assert block == out


OPTION_CLASSES = [
    cls
    for name in importers.names()
    for cls in (importers.get(name).Options, importers.get(name).WriteOptions)
    if cls is not None
]
FIELDS = [(cls, f.name) for cls in OPTION_CLASSES for f in dataclasses.fields(cls)]


@settings(max_examples=300, deadline=None)
@given(
    field=st.sampled_from(FIELDS),
    text=st.one_of(
        st.text(max_size=12),
        st.sampled_from(["none", "NaN", "inf", "-1", "0", "1e400", "true", "3.5", " 7 "]),
    ),
)
def test_any_text_gives_the_options_type_or_one_error(
    field: tuple[type[FormatOptions], str], text: str
) -> None:
    """Whatever follows `-O KEY=`, the result is a value of the option's declared type (one of
    its choices), or a ToolkitError naming the key; never another exception."""
    cls, key = field
    try:
        options = cls.parse({key: text})
    except ToolkitError as e:
        assert key in str(e) and "\n" not in str(e)
        return
    value = getattr(options, key)
    kind = field_types(cls)[key]
    allowed = choices(kind)
    if allowed:
        assert value in allowed or value is None
    else:
        members = [m for m in typing.get_args(kind) or (kind,) if typing.get_origin(m) is None]
        literals = [c for m in typing.get_args(kind) if typing.get_origin(m) is typing.Literal for c in typing.get_args(m)]  # fmt: skip
        assert value in literals or isinstance(value, tuple(members)), (key, text, value)


def test_toolkit_alone_prints_the_help(cli: Cli) -> None:
    code, out, err = cli()
    assert code == 0 and err == ""
    assert out.startswith("Usage: toolkit [OPTIONS] COMMAND") and "formats" in out
