"""The old module paths droid.brain keeps after its split into subpackages (issue 43 item 5).

A device package outside the repository imports ``droid.brain.layouts``, ``.classes`` and
``.registry`` (docs/architecture.md "Adding a device class"): each old path still imports, hands
on every public name of the module that moved, and warns naming the new path.  Nothing inside
``droid`` imports through them, by any spelling (a string module path included).
"""
from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import pytest

DROID = Path(__file__).resolve().parents[2] / "droid"

#: old path -> new path
MOVED = {
    "droid.brain.layouts": "droid.brain.db.layouts",
    "droid.brain.classes": "droid.brain.cell.classes",
    "droid.brain.registry": "droid.brain.cell.registry",
}


@pytest.mark.parametrize("old, new", sorted(MOVED.items()))
def test_an_old_path_warns_and_hands_on_the_moved_modules_names(old, new):
    sys.modules.pop(old, None)
    with pytest.warns(DeprecationWarning, match=re.escape(f"{old} is deprecated: it moved to {new}")):
        shim = importlib.import_module(old)
    moved = importlib.import_module(new)
    public = [n for n in vars(moved) if not n.startswith("_")]
    assert public and [n for n in public if getattr(shim, n, None) is not getattr(moved, n)] == []


def test_nothing_in_droid_imports_through_an_old_path():
    names = "|".join(re.escape(old.rsplit(".", 1)[1]) for old in MOVED)
    old_path = re.compile(rf"\bdroid\.brain\.({names})\b|\bfrom droid\.brain import [^\n#]*\b({names})\b")
    shims = {DROID / "brain" / f"{old.rsplit('.', 1)[1]}.py" for old in MOVED} | {DROID / "brain" / "_moved.py"}
    found = [f"{p.relative_to(DROID.parent)}:{i}: {line.strip()}"
             for p in sorted(DROID.rglob("*")) if p.suffix in (".py", ".toml") and p not in shims
             for i, line in enumerate(p.read_text().splitlines(), 1) if old_path.search(line)]
    assert found == []
