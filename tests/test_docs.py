"""Every code block of the README and of docs/*.md still runs or parses (docs/index.md,
"Development", states the rules):

- ```python blocks run in a scratch folder that holds `datasets/` (the bundled samples) and
  two datasets of different beam counts under `out/datasets/` (the corridor imported from the
  bundled CARMEN log, as `make demo` does, and a simulated 361-beam building); a first line
  `# needs: ITEM, ITEM (remark)` runs the block only when every item is an existing path
  there (globs allowed), else it is only compiled; without it, a block that uses names it
  does not define or relative paths (out/..., datasets/..., ../...) the folder lacks is
  only compiled too;
- ```sql blocks run in DuckDB in that folder, under the same rule (`-- needs: ...`);
- in ```sh, ```console and unlabelled blocks, each `toolkit CMD ...` line names a command
  that exists and only flags it has, each `make TARGET` a target of the Makefile;
- relative links between the pages resolve (pages other helpers are writing may be missing
  until they are merged: those are skipped, by name).

Pages added later are picked up by the glob.
"""

from __future__ import annotations

import ast
import builtins
import contextlib
import glob
import io
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: pages the README links that other branches add; skipped (not failed) while missing
PENDING: set[str] = set()  # pages announced before they land (none now)
SHELL = {"", "sh", "shell", "bash", "console"}
FENCE = re.compile(r"^(`{3,})\s*([\w+-]*)\s*$")
FLAG = re.compile(r"(?<![\w/.=-])(--[A-Za-z][\w-]*|-[A-Za-z])(?![\w-])")


@dataclass(frozen=True)
class Block:
    page: Path
    line: int  # of the first line of code
    lang: str
    code: str

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"

    def needs(self) -> list[str] | None:
        """The items of a first line `# needs: ...` (`-- needs:` in SQL), remarks dropped."""
        first = self.code.lstrip("\n").split("\n", 1)[0].strip()
        m = re.match(r"^(?:#|--)\s*needs:\s*(.*)$", first)
        if m is None:
            return None
        text = re.sub(r"\([^)]*\)", "", m.group(1))
        return [item.strip() for item in text.split(",") if item.strip()]


def blocks(page: Path) -> Iterator[Block]:
    lines = page.read_text().splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        fence, lang, start = m.group(1), m.group(2).lower(), i + 1
        i += 1
        while i < len(lines) and lines[i].strip() != fence:
            i += 1
        yield Block(page, start + 1, lang, "\n".join(lines[start:i]) + "\n")
        i += 1


ALL = [b for page in PAGES for b in blocks(page)]
PYTHON = [b for b in ALL if b.lang in ("python", "py")]
SQL = [b for b in ALL if b.lang == "sql"]
COMMANDS = [b for b in ALL if b.lang in SHELL]


def test_pages_are_found() -> None:
    names = {p.name for p in PAGES}
    assert {"README.md", "index.md", "dataset.md", "design.md"} <= names
    assert PYTHON and COMMANDS and SQL


# ---------------------------------------------------------------- the scratch folder


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`datasets/` and, as after `make demo`, `out/datasets/corridor` (181 beams, imported from
    the bundled CARMEN log by `toolkit import`) and `out/datasets/building361` (361 beams)."""
    from tests.conftest import toolkit_process
    from toolkit import save
    from toolkit.sim import simulate

    root = tmp_path_factory.mktemp("docs")
    (root / "datasets").symlink_to(ROOT / "datasets")  # read only
    log = root / "datasets/corridor-carmen/sim.log.gz"
    done = toolkit_process("import", "auto", log, "--out", root / "out/datasets/corridor")
    assert done.returncode == 0, done.stderr
    save(
        simulate("building", seed=0, beams=361, scans=300).dataset,
        root / "out/datasets/building361",
    )
    return root


def satisfied(block: Block, where: Path) -> bool:
    needs = block.needs()
    return needs is None or all(glob.glob(str(where / item)) for item in needs)


def missing(block: Block, where: Path) -> list[str]:
    """What a Python block uses that the scratch folder lacks: names it never defines (`cur`,
    `ds` from an earlier block) and relative paths in its strings (`out/datasets/intel`,
    `../shared/...`). Such a block is compiled, not run, even without `# needs:`."""
    tree = ast.parse(block.code)
    defined = set(dir(builtins)) | {"__name__", "__file__"}
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store | ast.Del):
            defined.add(node.id)
        elif isinstance(node, ast.Import | ast.ImportFrom):
            defined.update((a.asname or a.name).split(".")[0] for a in node.names)
        elif isinstance(node, ast.FunctionDef | ast.ClassDef | ast.AsyncFunctionDef):
            defined.add(node.name)
            defined.update(a.arg for a in ast.walk(node.args) if isinstance(a, ast.arg))
        elif isinstance(node, ast.Lambda):
            defined.update(a.arg for a in ast.walk(node.args) if isinstance(a, ast.arg))
    free = sorted({n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and n.id not in defined})
    paths = [
        n.value
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant)
        and isinstance(n.value, str)
        and re.match(r"^(\.\./|out/|datasets/)[^\s'\"]*$", n.value)
        and not glob.glob(str(where / n.value))
    ]
    return free + paths


def run_python(block: Block, where: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, object]:
    """Execute the block as a script in `where`; its namespace."""
    code = compile(block.code, block.where, "exec")
    monkeypatch.chdir(where)
    namespace: dict[str, object] = {"__name__": "__main__"}
    with contextlib.redirect_stdout(io.StringIO()) as out:
        exec(code, namespace)
    namespace["__stdout__"] = out.getvalue()
    return namespace


@pytest.mark.parametrize("block", PYTHON, ids=[b.where for b in PYTHON])
def test_python_block_runs(block: Block, workdir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    compile(block.code, block.where, "exec")  # a syntax error fails even a block that needs data
    if not satisfied(block, workdir):
        pytest.skip(f"compiled only: needs {block.needs()}")
    if block.needs() is None and (lacks := missing(block, workdir)):
        pytest.skip(f"compiled only: uses {lacks}, not in the scratch folder")
    run_python(block, workdir, monkeypatch)


@pytest.mark.parametrize("block", SQL, ids=[b.where for b in SQL])
def test_sql_block_runs(block: Block, workdir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    duckdb = pytest.importorskip("duckdb")
    if not satisfied(block, workdir):
        pytest.skip(f"needs {block.needs()}")
    monkeypatch.chdir(workdir)
    rows = duckdb.sql(block.code).fetchall()
    assert rows, f"{block.where}: no rows"


# ---------------------------------------------------------------- the README's example


def readme_example() -> Block:
    examples = [b for b in PYTHON if b.page.name == "README.md"]
    assert len(examples) == 1, "the README has one Python example"
    return examples[0]


def test_readme_example_is_five_lines_and_runs_on_the_bundled_data(
    workdir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    block = readme_example()
    lines = [ln for ln in block.code.splitlines() if ln.strip()]
    assert len(lines) == 5, block.code
    assert block.needs() is None  # runs as written
    ns = run_python(block, workdir, monkeypatch)
    printed = str(ns["__stdout__"])
    assert "2000 scans x 181 beams" in printed
    traj = ns["traj"]
    assert list(traj.columns) == ["t", "x", "y", "theta"] and len(traj) == 2000  # type: ignore[attr-defined]


# ---------------------------------------------------------------- reading many datasets


def doc_block(page: str, lang: str, marker: str) -> Block:
    found = [b for b in ALL if b.page.name == page and b.lang == lang and marker in b.code]
    assert len(found) == 1, f"{page}: one {lang} block with {marker!r}"
    return found[0]


def test_many_datasets_recipes_read_different_beam_counts(
    workdir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """docs/dataset.md's recipes on 181- and 361-beam datasets, where the one-call read
    fails (the issue's ArrowTypeError)."""
    import pandas as pd
    import pyarrow as pa

    monkeypatch.chdir(workdir)
    paths = sorted(glob.glob("out/datasets/*/scans.parquet"))
    with pytest.raises((pa.ArrowTypeError, pa.ArrowInvalid)):
        pd.read_parquet(paths)
    want = {"building361": (300, 361), "corridor": (2000, 181)}

    ns = run_python(doc_block("dataset.md", "python", "pd.concat("), workdir, monkeypatch)
    scans = ns["scans"]
    assert isinstance(scans, pd.DataFrame)
    got = {
        name: (len(group), {len(r) for r in group["ranges"]})
        for name, group in scans.groupby("dataset")
    }
    assert got == {k: (n, {b}) for k, (n, b) in want.items()}

    ns = run_python(doc_block("dataset.md", "python", "pds.dataset("), workdir, monkeypatch)
    table = ns["table"]
    assert isinstance(table, pa.Table) and table.num_rows == 2300
    assert sorted({len(r) for r in table.column("ranges").to_pylist()}) == [181, 361]

    duckdb = pytest.importorskip("duckdb")
    rows = duckdb.sql(doc_block("dataset.md", "sql", "GROUP BY dataset").code).fetchall()
    assert {name: (int(n), int(b)) for name, n, b in rows} == want


# ---------------------------------------------------------------- commands


def toolkit_lines(block: Block) -> Iterator[tuple[str, list[str]]]:
    """(line, words) of every `toolkit ...` line (continuations joined, comments dropped)."""
    text = block.code.replace("\\\n", " ")
    for line in text.splitlines():
        line = re.sub(r"^\s*\$\s+", "", line)
        line = re.sub(r"\s#.*$", "", line).strip()
        words = line.split()
        if words and (words[0] == "toolkit" or words[0].endswith("/toolkit")):
            yield line, words[1:]
        elif words[:3] == ["python", "-m", "toolkit"]:
            yield line, words[3:]


def make_lines(block: Block) -> Iterator[str]:
    for line in block.code.splitlines():
        words = re.sub(r"\s#.*$", "", line).split()
        if words[:1] == ["make"]:
            yield from (w for w in words[1:] if "=" not in w and not w.startswith("-"))


@pytest.fixture(scope="module")
def cli_options() -> dict[str, set[str]]:
    """Per command (and '' for the top level), every option string `--help` lists."""
    import typer

    from toolkit.app.cli import app

    group = typer.main.get_command(app)  # a click group (typer may bundle its own click)
    ctx = group.make_context("toolkit", ["--help"], resilient_parsing=True)

    def opts(cmd: Any) -> set[str]:  # noqa: ANN401 (a click command)
        found = {"--help"}
        for p in cmd.get_params(ctx):
            if p.param_type_name == "option":
                found.update(p.opts)
                found.update(p.secondary_opts)
        return found

    assert hasattr(group, "commands")
    out = {name: opts(cmd) for name, cmd in group.commands.items()}
    out[""] = opts(group)
    return out


@pytest.mark.parametrize("block", COMMANDS, ids=[b.where for b in COMMANDS])
def test_command_lines_name_real_commands_and_flags(
    block: Block, cli_options: dict[str, set[str]]
) -> None:
    targets = set(re.findall(r"^([\w.-]+)\s*:", (ROOT / "Makefile").read_text(), re.M))
    for target in make_lines(block):
        assert target in targets, f"{block.where}: make {target}: no such Makefile target"
    for line, words in toolkit_lines(block):
        command = next((w for w in words if not w.startswith("-")), "")
        if words and words[0].startswith("-"):
            command = ""  # `toolkit --help`: the top level's own options
        assert command in cli_options, f"{block.where}: {line!r}: no command {command!r}"
        rest = " ".join(words[words.index(command) + 1 :] if command else words)
        unknown = [f for f in FLAG.findall(rest) if f not in cli_options[command]]
        assert not unknown, f"{block.where}: {line!r}: toolkit {command} has no {unknown}"


# ---------------------------------------------------------------- links


def slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


#: the journals (docs/journal/) keep old commands as they were run: their links are checked,
#: not their code
JOURNALS = sorted((ROOT / "docs" / "journal").glob("*.md"))
LINKS = [
    (page, target)
    for page in [*PAGES, *JOURNALS]
    for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text())
    if not re.match(r"^[a-z]+:", target)  # http:, https:, mailto:
]


@pytest.mark.parametrize("page,target", LINKS, ids=[f"{p.name}->{t}" for p, t in LINKS])
def test_relative_links_resolve(page: Path, target: str) -> None:
    path, _, anchor = target.partition("#")
    dest = (page.parent / path).resolve() if path else page
    if not dest.exists() and dest.name in PENDING:
        pytest.skip(f"{dest.name} comes from another branch")
    assert dest.exists(), f"{page.name}: link to {target}: no such file"
    if anchor and dest.suffix == ".md":
        headings = re.findall(r"^#+\s+(.*)$", dest.read_text(), re.M)
        assert anchor in {slug(h) for h in headings}, f"{page.name}: no heading #{anchor}"


def test_every_page_is_listed_in_the_index_and_the_readme() -> None:
    """A page added to docs/ is reachable: docs/index.md and the README link it."""
    pages = {p.name for p in PAGES if p.parent == ROOT / "docs" and p.name != "index.md"}
    index = set(re.findall(r"\]\(([\w.-]+\.md)", (ROOT / "docs/index.md").read_text()))
    readme = set(re.findall(r"\]\(docs/([\w.-]+\.md)", (ROOT / "README.md").read_text()))
    assert pages - index == set(), "not in docs/index.md"
    assert pages - readme == set(), "not linked from the README"
    assert index >= PENDING and readme >= PENDING  # the other branches' pages are announced
