"""The import-layering check the tests share (docs/design.md §7): which ``droid`` modules a source file imports."""
from __future__ import annotations

import ast
from pathlib import Path

DROID = Path(__file__).resolve().parents[1] / "droid"


def droid_imports(path: Path) -> list[str]:
    """The absolute imports of ``droid`` or ``droid.*`` in one source file (``import x`` and ``from x import``)."""
    names: list[str] = []
    for node in ast.walk(ast.parse(Path(path).read_text())):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return [n for n in names if n == "droid" or n.startswith("droid.")]


def within(name: str, modules) -> bool:
    """``name`` is one of ``modules`` or inside one of them."""
    return any(name == m or name.startswith(m + ".") for m in modules)
