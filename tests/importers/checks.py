"""Checks the importer tests share: damaged copies of a clean file, and the CLI's answer to
input that is no log at all."""

from __future__ import annotations

from pathlib import Path

from tests.conftest import Cli

DAMAGES = ("truncate", "flip", "prefix", "empty", "huge")


def damaged(
    clean: bytes, damage: str, where: float, bit: int, prefix: bytes, huge: bytes, insert: bool
) -> bytes:
    """`clean` cut at, bit-flipped at or overwritten (or, with `insert`, widened) with `huge`
    at the fraction `where`; or `prefix` repeated before it; or nothing."""
    data = bytearray(clean)
    at = min(int(where * len(data)), len(data) - (1 if insert else len(huge)))
    if damage == "truncate":
        data = data[:at]
    elif damage == "flip":
        data[at] ^= 1 << bit
    elif damage == "prefix":
        data = bytearray(prefix * (bit + 1)) + data
    elif damage == "empty":
        data = bytearray()
    else:
        data[at : at if insert else at + len(huge)] = huge
    return bytes(data)


def assert_bad_input_is_one_line(cli: Cli, fmt: str, src: Path, tmp_path: Path) -> None:
    """`toolkit import FMT SRC`: exit status 1, one line naming the file, nothing written."""
    out = tmp_path / "ds"
    code, _, err = cli("import", fmt, str(src), "--out", str(out))
    assert code == 1
    assert len(err.strip().splitlines()) == 1 and err.startswith("error: ") and str(src) in err
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == [src.name]
