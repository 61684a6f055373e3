"""The packages' imports follow the design's data flow: core (`toolkit`), formats
(`importers`), `reports`, then the application (`toolkit.app`) on top; and no two modules
import each other, even through imports inside functions.

`python -m tests.test_layers` prints the module graph (one line per import between the
project's modules) and its layer violations and cycles.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("toolkit", "importers", "reports")
#: A module may import only modules of its own layer or of layers below.
LAYERS = {"toolkit": 0, "importers": 1, "reports": 2, "toolkit.app": 3}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            found[module_name(path)] = path
    return found


def _resolve(name: str, known: dict[str, Path]) -> str | None:
    """The project module that `import name` loads last (a submodule, else its package)."""
    while name:
        if name in known:
            return name
        name = name.rpartition(".")[0]
    return None


def imports(module: str, path: Path, known: dict[str, Path]) -> Iterator[tuple[str, int]]:
    """(imported project module, line) for every import in the file, at any depth,
    TYPE_CHECKING blocks excepted (they do not run)."""
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip.update(id(n) for n in ast.walk(node))
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            for alias in node.names:
                target = _resolve(alias.name, known)
                if target:
                    yield target, node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            for alias in node.names:
                target = _resolve(f"{base}.{alias.name}", known)
                if target:
                    yield target, node.lineno


def layer(module: str) -> int:
    if module in ("toolkit.app", "toolkit.__main__") or module.startswith("toolkit.app."):
        return LAYERS["toolkit.app"]
    return LAYERS[module.split(".")[0]]


def graph() -> dict[str, set[str]]:
    known = modules()
    return {
        m: {t for t, _ in imports(m, p, known) if t != m and not m.startswith(t + ".")}
        for m, p in known.items()
    }


def violations() -> list[str]:
    known = modules()
    bad = []
    for m, p in known.items():
        for target, line in imports(m, p, known):
            if layer(target) > layer(m):
                bad.append(f"{p.relative_to(ROOT)}:{line}: {m} imports {target} (a layer above)")
    return bad


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    sys.setrecursionlimit(10_000)

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_no_import_from_a_lower_layer_into_a_higher_one() -> None:
    assert violations() == []


def test_no_cycle_between_modules() -> None:
    assert cycles(graph()) == []


def test_the_core_never_loads_the_application() -> None:
    """Importing every core module leaves importers, reports and toolkit.app unloaded."""
    import subprocess

    core = [m for m in modules() if m.split(".")[0] == "toolkit" and layer(m) == 0]
    code = (
        "import importlib, sys\n"
        f"for m in {core!r}: importlib.import_module(m)\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('importers', 'reports')"
        " or m.startswith('toolkit.app')))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]"


if __name__ == "__main__":
    edges = graph()
    for m in sorted(edges):
        for t in sorted(edges[m]):
            print(f"{m} -> {t}")
    print(f"{len(edges)} modules, {sum(map(len, edges.values()))} imports")
    print("layer violations:", violations() or "none")
    print("cycles:", cycles(edges) or "none")
