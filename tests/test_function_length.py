"""Issue 25's target: no function in droid/ longer than 80 lines.

Walks every module under droid/ with ast and names each function (or method)
whose definition spans more than MAX_LINES lines (``def`` line to its last line).

One function is exempt, for a measured reason: droid.kinematics.opw.ik_hinted,
the pure-Python 8-solution inverse (~10 us a pose; bench/bench_kinematics.py's
target is 15 us).  Its body is one shoulder x elbow loop with the joint wraps
written out inline on purpose; any split under 80 lines needs helper calls per
elbow (at least 8 calls a pose), and a call costs 0.1-0.15 us here: 9-11 % of
the pose (issue 25's refactor, 2026-11-27).  The exemption fails as soon as the
function gets short, so it cannot outlive its reason.
"""
from __future__ import annotations

import ast
from pathlib import Path

import droid

MAX_LINES = 80
ROOT = Path(droid.__file__).resolve().parent
#: "path:function" -> why it may stay longer than MAX_LINES.
EXEMPT = {
    "droid/kinematics/opw.py:ik_hinted": "hot pure-Python IK: a split costs helper calls per elbow (~10 % a pose)",
}


def function_lengths(root: Path = ROOT):
    """(lines, "path:function", line number) of every function under *root*."""
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        rel = path.relative_to(root.parent).as_posix()
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield node.end_lineno - node.lineno + 1, f"{rel}:{node.name}", node.lineno


def test_no_function_over_80_lines():
    long = [f"{n} lines: {where} (line {line})" for n, where, line in function_lengths()
            if n > MAX_LINES and where not in EXEMPT]
    assert not long, f"functions over {MAX_LINES} lines (issue 25):\n" + "\n".join(long)


def test_every_exemption_is_still_needed():
    lengths = {where: n for n, where, _ in function_lengths()}
    stale = [where for where in EXEMPT if lengths.get(where, 0) <= MAX_LINES]
    assert not stale, f"exempt but no longer over {MAX_LINES} lines (drop them from EXEMPT): {stale}"
