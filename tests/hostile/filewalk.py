"""Walking the numbers of a TOML file and writing hostile copies of it (tests/hostile/test_numeric_files.py).

:func:`leaves` finds every numeric value of a parsed file (in lists: the first and the last
element), :func:`dumps` writes a parsed file back as TOML (top-level keys with inline tables:
valid TOML that parses to the same dict; ``nan``/``inf`` as TOML's literals), so a copy with
one number replaced is real input for a loader.
"""
from __future__ import annotations

import copy
import json
from typing import Any, Iterator

from droid.numbers import show_number

Path_ = tuple  # keys and indices from the top of the file to one number


def leaves(data: Any, path: Path_ = ()) -> Iterator[tuple[Path_, int | float]]:
    """(path, value) of every int/float (not bool) in ``data``; of a list only the first and the last."""
    if isinstance(data, dict):
        for k, v in data.items():
            yield from leaves(v, (*path, k))
    elif isinstance(data, list):
        idx = sorted({0, len(data) - 1}) if data else []
        for i in idx:
            yield from leaves(data[i], (*path, i))
    elif isinstance(data, (int, float)) and not isinstance(data, bool):
        yield path, data


def key_of(path: Path_) -> str:
    """The name the error must hold: the last table key on the path."""
    return next(p for p in reversed(path) if isinstance(p, str))


def replaced(data: Any, path: Path_, value: Any) -> Any:
    out = copy.deepcopy(data)
    t = out
    for p in path[:-1]:
        t = t[p]
    t[path[-1]] = value
    return out


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return show_number(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {v!r} as TOML")


def dumps(data: dict) -> str:
    return "".join(f"{json.dumps(k)} = {_value(v)}\n" for k, v in data.items())
