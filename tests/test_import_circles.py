"""No import circles in ``droid`` (issue 25 item 4: "no import circles").

Every import of a ``droid`` module, at the top of a file or inside a function (a late import
still ties the two modules together), is an arrow between two source files; a package's
``__init__.py`` stands for the package.  The arrows must form no loop: a lower layer that
reaches up for one name (a job type, a default rate, a reading's class) makes the two layers
one.  The test names each loop found, file by file.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DROID = ROOT / "droid"


def _module_file(name: str) -> Path | None:
    base = ROOT.joinpath(*name.split("."))
    if base.with_suffix(".py").is_file():
        return base.with_suffix(".py")
    if (base / "__init__.py").is_file():
        return base / "__init__.py"
    return None


def _arrows(path: Path) -> set[Path]:
    out: set[Path] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            # ``from droid.pkg import mod`` names the submodule when there is one
            names = [f"{node.module}.{a.name}" if _module_file(f"{node.module}.{a.name}") else node.module
                     for a in node.names]
        for n in names:
            if n == "droid" or n.startswith("droid."):
                f = _module_file(n)
                if f is not None and f != path:
                    out.add(f)
    return out


def import_graph() -> dict[Path, set[Path]]:
    return {p: _arrows(p) for p in sorted(DROID.rglob("*.py"))}


def circles(graph: dict[Path, set[Path]]) -> list[list[Path]]:
    """The strongly connected parts of more than one file (Tarjan), each a list of files."""
    index: dict[Path, int] = {}
    low: dict[Path, int] = {}
    stack: list[Path] = []
    on: set[Path] = set()
    found: list[list[Path]] = []

    def visit(v: Path) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                on.discard(w)
                part.append(w)
                if w == v:
                    break
            if len(part) > 1:
                found.append(sorted(part))

    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_the_finder_sees_a_circle_through_a_late_import(tmp_path):
    a, b, c = (tmp_path / n for n in ("a.py", "b.py", "c.py"))
    assert circles({a: {b}, b: {c}, c: {a}}) == [sorted([a, b, c])]
    assert circles({a: {b}, b: {c}, c: set()}) == []
    src = "def f():\n    from droid.sim.world import DEFAULT_RATE_HZ\n    return DEFAULT_RATE_HZ\n"
    mod = tmp_path / "late.py"
    mod.write_text(src)
    assert DROID / "sim" / "world.py" in _arrows(mod)
    mod.write_text("from droid.observe import foxglove\n")
    assert DROID / "observe" / "foxglove.py" in _arrows(mod)


def test_droid_has_no_import_circles():
    found = circles(import_graph())
    assert not found, "import circles:\n" + "\n".join(
        " <-> ".join(str(p.relative_to(ROOT)) for p in part) for part in found)
