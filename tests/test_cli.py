"""The command-line contract: --help everywhere, exit 1 with one line on user errors."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT, Cli, toolkit_process
from toolkit.app.cli import app


def assert_one_line_error(result: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert result.returncode == 1, result
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    for needle in needles:
        assert needle in lines[0]


@pytest.mark.slow
def test_every_command_answers_help() -> None:
    names = [c.name for c in app.registered_commands]
    assert {"import", "info"} <= set(names)
    for name in names:
        result = toolkit_process(name, "--help")
        assert result.returncode == 0, (name, result.stderr)
        assert "Usage" in result.stdout


def test_unknown_format_names_the_known_ones(tmp_path: Path) -> None:
    src = tmp_path / "x.log"
    src.write_text("hello\n")
    assert_one_line_error(
        toolkit_process("import", "nosuch", src, "--out", tmp_path / "d"), "unknown format"
    )
    assert not (tmp_path / "d").exists()


def test_missing_source_is_named(tmp_path: Path) -> None:
    missing = tmp_path / "missing.log"
    assert_one_line_error(
        toolkit_process("import", "auto", missing, "--out", tmp_path / "d"), str(missing)
    )


def test_undetectable_format_says_so(tmp_path: Path) -> None:
    src = tmp_path / "notes.txt"
    src.write_text("dear diary, the robot drove around\n")
    assert_one_line_error(toolkit_process("import", "auto", src, "--out", tmp_path / "d"), "format")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_info_on_a_non_dataset(tmp_path: Path) -> None:
    assert_one_line_error(toolkit_process("info", tmp_path), "not a dataset")


@pytest.mark.parametrize("bad", ["KEY", "=v"])
def test_malformed_format_option(tmp_path: Path, bad: str) -> None:
    src = tmp_path / "x.log"
    src.write_text("x\n")
    assert_one_line_error(
        toolkit_process("import", "auto", src, "--out", tmp_path / "d", "-O", bad), "KEY=VALUE"
    )


def test_interrupt_exits_130_and_writes_nothing(tmp_path: Path) -> None:
    """Ctrl-C during a command: status 130, a line saying so, no output left behind."""
    import signal
    import time

    out = tmp_path / "sim"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "toolkit",
            "simulate",
            "building",
            "--out",
            str(out),
            "--format",
            "dataset",
            "--scans",
            "200000",
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(6)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_usage_errors_are_one_line_not_internal(tmp_path: Path) -> None:
    result = toolkit_process("import", "carmen", tmp_path / "x.log")  # no --out
    assert_one_line_error(result, "--out")
    assert "internal" not in result.stderr
    assert_one_line_error(toolkit_process("info", tmp_path, "--no-such-flag"), "no-such-flag")


def test_auto_reads_a_simulate_output_directory(tmp_path: Path, cli: Cli) -> None:
    """A directory holding one log (plus truth files) stands for that log; prose is no log."""
    for sample in ("corridor-carmen", "corridor-aria", "building-rawseeds"):
        code, _, err = cli("import", "auto", ROOT / "datasets" / sample, "--out", tmp_path / sample)
        assert code == 0, err
    code, _, err = cli(
        "import", "carmen", ROOT / "datasets" / "corridor-aria", "--out", tmp_path / "x"
    )
    assert code == 1 and "no carmen log in this directory" in err
    code, _, err = cli("import", "auto", ROOT / "README.md", "--out", tmp_path / "y")
    assert code == 1 and "cannot tell the format" in err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_plain_values_are_coerced_as_typer_coerces_them(tmp_path: Path) -> None:
    """`toolkit.app.cli._PlainValues` (no pydantic) gives what typer's own adapter gives for
    every parameter of every command: strs, paths (existing, missing, a directory, several),
    defaults of their own type; and the same error for what it hands on to typer."""
    import typer

    from toolkit.app import cli

    if not hasattr(cli, "_typer_runtime_param"):  # another typer: it coerces everything itself
        pytest.skip(f"typer {typer.__version__} has other internals; no shortcut installed")
    (tmp_path / "f").write_text("x")
    values: dict[object, list[object]] = {
        str: ["gaussian", "", "a b"],
        Path: [str(tmp_path), str(tmp_path / "f"), str(tmp_path / "missing"), "rel/x"],
        float: [0.0, 2.5, "0.5", "abc"],
        int: [3, "7", "x"],
        bool: [True, False],
    }
    values[list[Path]] = [(str(tmp_path), str(tmp_path / "f")), ["a"]]
    values[list[str]] = [("slam.loops=false", "a=b"), ["x"], ()]
    group = typer.main.get_command(cli.app)
    checked = 0
    for command in [group, *group.commands.values()]:  # type: ignore[attr-defined]
        ctx = command.make_context("toolkit", [], resilient_parsing=True)
        for param in command.params:
            desc = param.type_descriptor
            ours = cli.typer.core.build_runtime_param(desc)
            theirs = cli._typer_runtime_param(desc)
            for value in [None, *values.get(desc.annotation, [])]:
                try:
                    expected: object = theirs.coerce(value, param, ctx)
                except typer.BadParameter as e:
                    with pytest.raises(typer.BadParameter, match=re.escape(str(e.message))):
                        ours.coerce(value, param, ctx)
                    continue
                got = ours.coerce(value, param, ctx)
                assert got == expected and type(got) is type(expected), (param.name, value)
                checked += 1
    assert checked > 40
