"""Every numeric argument of every DROID program and its range, found by introspection (issue 16).

Each program of :data:`droid.programs.PROGRAMS` is run with ``parse_args`` of
:class:`droid.cli.ArgumentParser` intercepted: the parser it built (with its sub-commands)
is taken and the program stops there -- nothing runs, no cell is read.  The programs are
imported by name, as the launcher starts them (``python -m MODULE``), so this module
imports none of them itself.

``python -m droid.cliranges`` prints the Markdown table of docs/architecture.md
("Numeric arguments"); tests/hostile/test_numeric_args.py checks every entry against
hostile values and the table against the document.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from dataclasses import dataclass

from droid import cli
from droid.brain.cell.registry import programs

#: argv prefixes a main dispatches on before it builds another parser (``droid-sim truth``, ``droid-sim lockstep``).
ENTRIES = {"droid-sim": [[], ["truth"], ["lockstep"]]}


@dataclass(frozen=True)
class Argument:
    """One argument or option of one program (or sub-command)."""

    prog: str
    entry: tuple[str, ...]  # argv prefix that reaches the parser (ENTRIES)
    path: tuple[str, ...]  # sub-command names (droid-cell up, droid-kin ik, ...)
    parser: argparse.ArgumentParser
    action: argparse.Action

    @property
    def name(self) -> str:
        """The option's long name, or the positional's dest."""
        a = self.action
        return a.option_strings[-1] if a.option_strings else a.dest

    @property
    def command(self) -> str:
        return " ".join([self.prog, *self.entry, *self.path])

    @property
    def numeric(self) -> bool:
        """Takes a number: a bounded type, any of droid.cli's number types, int/float, or a number default."""
        t = self.action.type
        if t in (int, float) or hasattr(t, "span"):
            return True
        if t in (cli.finite_float, cli.positive_float, cli.positive_int, cli.non_negative_int, cli.integer):
            return True
        d = self.action.default
        return isinstance(d, (int, float)) and not isinstance(d, bool)


class _Captured(Exception):
    pass


def main_of(prog: str):
    """The ``main`` of a program (by its console-script name)."""
    return importlib.import_module(programs()[prog]).main


def collect() -> list[Argument]:
    """Every argument (taking a value) of every program and sub-command, in PROGRAMS order."""
    found: list[Argument] = []
    got: list = []
    original = cli.ArgumentParser.parse_args, cli.ArgumentParser.parse_intermixed_args

    def capture(self, args=None, namespace=None):
        got.append(self)
        raise _Captured

    def walk(prog, entry, p, path):
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sp in a.choices.items():
                    walk(prog, entry, sp, (*path, name))
            elif a.nargs != 0 and not isinstance(a, argparse._HelpAction):
                found.append(Argument(prog, tuple(entry), path, p, a))

    cli.ArgumentParser.parse_args = cli.ArgumentParser.parse_intermixed_args = capture  # either way of parsing
    try:
        for prog in programs():
            for entry in ENTRIES.get(prog, [[]]):
                got.clear()
                try:
                    main_of(prog)(list(entry))
                except _Captured:
                    pass
                if len(got) != 1:
                    raise RuntimeError(f"{prog} {' '.join(entry)}: built {len(got)} parsers before parsing")
                walk(prog, entry, got[0], ())
    finally:
        cli.ArgumentParser.parse_args, cli.ArgumentParser.parse_intermixed_args = original
    return found


def markdown(args: list[Argument] | None = None) -> str:
    """The table of every numeric argument's range (docs/architecture.md, "Numeric arguments")."""
    rows = ["| program | argument | range |", "|---|---|---|"]
    for a in args if args is not None else collect():
        if not a.numeric or a.name == "--ready-fd":  # every program shell's; stated once under the table
            continue
        span = getattr(a.action.type, "span", None)
        hidden = " (hidden)" if a.action.help is argparse.SUPPRESS else ""
        rows.append(f"| `{a.command}` | `{a.name}`{hidden} | {f'`{span}`' if span else 'checked after parsing'} |")
    return "\n".join(rows) + "\n"


if __name__ == "__main__":
    sys.stdout.write(markdown())
