"""Every DROID program: console-script name -> module with ``main(argv=None) -> int``.

:data:`PROGRAMS` is a view of the device registry (:mod:`droid.brain.cell.registry`): each
device package declares its programs in its ``device.py``.  The launcher starts programs
as ``python -m MODULE`` with this interpreter, so a cell runs the same whether or not the
console scripts are on PATH; the console scripts in pyproject.toml point at the same
modules (tests/brain/test_cli_input.py checks both directions).
"""
from __future__ import annotations


def __getattr__(name: str):
    if name == "PROGRAMS":  # PEP 562: computed from the registry on first use
        from droid.brain.cell.registry import programs

        return programs()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
