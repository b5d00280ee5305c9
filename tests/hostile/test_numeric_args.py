"""Every numeric argument of every program (issue 16, "Bad input"; docs/design.md §6).

The parsers are not listed by hand: droid.cliranges runs every program of
droid.programs.PROGRAMS (= pyproject.toml's console scripts) with ``parse_args`` intercepted,
so every argument and option of every program and sub-command is found by introspection --
a new option that takes a number without a stated range fails
:func:`test_every_numeric_argument_has_a_stated_range` at once, and one missing from the
table of docs/architecture.md fails :func:`test_the_documented_table_is_the_programs_own`.

For every numeric argument the test tries extreme but finite values, negative zero,
subnormals, huge exponents and integers, values just outside each limit (the next float
past it), non-finite and malformed numbers: each must end the program with exit 2 and
one line on stderr naming the argument (and, when the number is out of range, the range),
never a traceback.  The refusal happens while parsing: ``parse_args`` is wrapped so that
an accepted command line raises instead of running the program -- nothing is started,
no cell is contacted, nothing moves (``cell_objects`` stays empty).  The one argument
whose range depends on others (droid-move's values: joint or cartesian targets, then
SECONDS) is checked after parsing against a cell that is not up: a value that got
through would end in exit 1 ("not up"), not 2.

The decisions where a program legitimately accepts an edge value are in ACCEPTED_EDGES.
The programs' mains run in this process (fast); a handful of subprocess runs of the
console scripts check that no traceback reaches a user.
"""
from __future__ import annotations

import argparse
import io
import math
import subprocess
import sys
from pathlib import Path

import pytest

import droid.cli as cli
from droid import cliranges
from droid.brain.db.shmdb import cell_objects
from tests.brain.cellutil import make_cell_file

ROOT = Path(__file__).resolve().parents[2]

#: Numbers whose range depends on other arguments: checked after parsing (before the cell is
#: contacted); see test_move_values_refused_before_the_cell_is_contacted.
POST_PARSE = {
    ("droid-move", "values"): "E1..E6 [counts] within the encoder limits, or X Y Z [mm] A B C [deg] "
                              "reachable, |A|, |B|, |C| <= 360 deg; then SECONDS in (0, 3600] s, "
                              "at least one heartbeat tick",
}

#: Numbers without a unit, and why (every other numeric argument names its unit in --help).
DIMENSIONLESS = {
    ("droid-mvs-board", "--spurious"): "a fraction",
    ("droid-mvs-board", "--drop"): "a probability",
    ("droid-mvs-board", "--seed"): "a seed",
    ("droid-ros2", "--domain"): "a ROS 2 domain id",
    ("droid-seamtrack", "--yaw-gain"): "a proportional gain",
    ("droid-seamtrack", "--pitch-gain"): "a proportional gain",
    ("droid-sim", "--seed"): "a seed",
    ("droid-calibrate", "--seed"): "a seed",
    ("droid-experiment", "--seed"): "a seed",
    ("droid-fault", "--drop"): "a probability",
    ("droid-fault", "--duplicate"): "a probability",
    ("droid-fault", "--seed"): "a seed",
    ("droid-web", "--port"): "a TCP port",
    ("droid-web", "--foxglove"): "a TCP port",
    ("droid-foxglove", "--port"): "a TCP port",
    ("*", "--ready-fd"): "a file descriptor (set by droid-cell up; hidden)",
}

#: Edge values a program accepts on purpose (test_the_edges_of_each_range_are_accepted):
ACCEPTED_EDGES = """
- "-0", "-0.0", "-0e5" where 0 is inside the range: zero (stored as +0.0; negative zero never
  reaches a program).
- the smallest positive subnormal (5e-324) for a duration in (0, max] s (--timeout, --seconds, ...):
  a wait that ends at once -- carried out, never an overflow.  Rates have a lower limit > 0 instead
  (a rate of 1e-320 Hz would be a period of inf s); droid-move's SECONDS must be one tick or more.
- the smallest positive subnormal for droid-seamtrack SPEED (0, 500] mm/s and --length (0, 10000] mm:
  a run that does not get anywhere (it ends on seam loss or Ctrl-C), not an error of the program.
- a leading "+" anywhere a number is asked for.
"""


class _Accepted(Exception):
    """Raised when a command line under test was accepted by the parser (nothing runs)."""


ARGS = cliranges.collect()
NUMERIC = [a for a in ARGS if a.numeric]
BOUNDED = [a for a in NUMERIC if (a.prog, a.action.dest) not in POST_PARSE]


def _id(a) -> str:
    return f"{a.command} {a.name}"


def test_the_programs_were_all_found():
    """The introspection reached every console script and the sub-commands."""
    import tomllib

    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert {a.prog for a in ARGS} == set(scripts)
    ids = {_id(a) for a in NUMERIC}
    for expected in ("droid-cell up --timeout", "droid-kin ik --prev", "droid-fault proxy --seed",
                     "droid-experiment run --jobs", "droid-seamtrack --length", "droid-sim --seed",
                     "droid-replay --from", "droid-move values"):
        assert expected in ids, sorted(ids)
    assert len(BOUNDED) >= 60, len(BOUNDED)


@pytest.mark.parametrize("item", NUMERIC, ids=[_id(a) for a in NUMERIC])
def test_every_numeric_argument_has_a_stated_range(item):
    """Its type is one of droid.cli's bounded types (the rule written once), with a unit unless
    DIMENSIONLESS says why not, and its --help line states the range."""
    prog, parser, action = item.prog, item.parser, item.action
    if (prog, action.dest) in POST_PARSE:
        return
    t = action.type
    assert hasattr(t, "span"), (f"{_id(item)} takes a number with no stated range: give it a "
                                f"droid.cli.bounded_float/bounded_int type")
    if not t.unit:
        assert (prog, item.name) in DIMENSIONLESS or ("*", item.name) in DIMENSIONLESS, \
            f"{_id(item)}: range {t.span} has no unit"
    if action.help is not argparse.SUPPRESS:
        text = " ".join(parser.format_help().split())
        assert f"range {t.span}" in text, f"{_id(item)}: --help does not state {t.span}"


def test_the_tables_are_not_stale():
    names = {(a.prog, a.name) for a in NUMERIC} | {("*", a.name) for a in NUMERIC}
    for key in DIMENSIONLESS:
        assert key in names, key
    assert set(POST_PARSE) <= {(a.prog, a.action.dest) for a in NUMERIC}


def test_the_documented_table_is_the_programs_own():
    doc = (ROOT / "docs" / "architecture.md").read_text()
    assert cliranges.markdown(ARGS) in doc, \
        "docs/architecture.md, Numeric arguments: paste the table of 'python -m droid.cliranges'"


def _just_outside(t) -> list[str]:
    """Values just past each limit of a bounded type (and the extremes beyond)."""
    lo, hi = t.lo, t.hi
    if t.integral:
        vals = [str(hi + 1), str(lo - 1), str(10**30), str(-10**30), "9" * 400]
        if lo > 0:
            vals += ["0", "-0"]
        return vals
    vals = [repr(math.nextafter(hi, math.inf)), repr(hi * (1 + 1e-9) + 1e-9)]
    if hi < 1e308:
        vals += ["1e308", "1.7976931348623157e308"]
    if lo > -1e308:
        vals += ["-1e308", "-1.7976931348623157e308"]
    if t.lo_open:
        vals.append(repr(float(lo)))
        if lo == 0:
            vals += ["-0", "-0.0", "0", "0e0", "-5e-324", "-1e-320"]
    else:
        vals.append(repr(math.nextafter(lo, -math.inf)))
        if lo > 0:
            vals += ["1e-320", "5e-324", "0", "-0", "-0.0"]
    return vals


#: Not numbers at all, or not finite: refused by every numeric argument.
MALFORMED = ["nan", "NaN", "-nan", "inf", "+inf", "-inf", "Infinity", "1e999", "-1e999", "0x10", "1_000",
             "", " ", " 1", "1 ", "１", "1e", "e3", "1,5", "0b1", "--", "1e+", "١"]
#: Not integers (for integer arguments).
NOT_INTEGER = ["1.0", "1.5", "1e3", "0.0", "-0.0"]


def _bad_values(t) -> list[str]:
    if not hasattr(t, "span"):  # (failed test_every_numeric_argument_has_a_stated_range)
        return MALFORMED
    return MALFORMED + (NOT_INTEGER if t.integral else []) + _just_outside(t)


def _argv(item, value: str) -> list[str]:
    """A command line that hands ``value`` to the argument (other required ones may be missing:
    argparse converts each value as it meets it, before it checks for missing arguments)."""
    parser, action = item.parser, item.action
    argv = [*item.entry, *item.path]
    if action.option_strings:
        opt = action.option_strings[-1]
        if action.nargs is None:
            return argv + [f"{opt}={value}"]
        n = action.nargs if isinstance(action.nargs, int) else 1
        return argv + [opt, value] + ["0"] * (n - 1)
    for a in parser._actions:  # the positionals before this one, filled with valid words
        if a is action:
            break
        if not a.option_strings and not isinstance(a, argparse._SubParsersAction):
            argv.append(str(next(iter(a.choices))) if a.choices else "x")
    return argv + ["--", value]


@pytest.fixture
def no_run(monkeypatch):
    """parse_args that raises _Accepted instead of returning: the program never runs."""
    original = cli.ArgumentParser.parse_args

    def guarded(self, args=None, namespace=None):
        raise _Accepted(original(self, args, namespace))

    monkeypatch.setattr(cli.ArgumentParser, "parse_args", guarded)


def _call(main, argv, capsys):
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err


@pytest.mark.parametrize("item", BOUNDED, ids=[_id(a) for a in BOUNDED])
def test_bad_numbers_exit_2_with_one_line_naming_the_argument(item, no_run, tmp_path, cell_name, capsys,
                                                               monkeypatch):
    prog, action = item.prog, item.action
    t = action.type
    name = argparse._get_action_name(action)
    monkeypatch.setenv("DROID_CELL", str(make_cell_file(tmp_path, cell_name)))  # a cell that is not up
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    outside = set(_just_outside(t)) if hasattr(t, "span") else set()
    main = cliranges.main_of(prog)
    for value in _bad_values(t):
        argv = _argv(item, value)
        try:
            code, err = _call(main, argv, capsys)
        except _Accepted:
            pytest.fail(f"{prog} {argv} was accepted")
        assert code == 2, (argv, err)
        assert "Traceback" not in err, (argv, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1, (argv, err)
        assert name in lines[0], (argv, err)
        if value in outside and (not value.startswith("-") or action.nargs is None):
            assert t.span in lines[0] or "not an integer" in lines[0], (argv, err)
    assert cell_objects(cell_name) == []  # nothing was created


@pytest.mark.parametrize("item", BOUNDED, ids=[_id(a) for a in BOUNDED])
def test_the_edges_of_each_range_are_accepted(item):
    """lo (or just above an open lo), hi, a leading '+', and -0 as +0 where 0 is inside."""
    t = item.action.type
    lo, hi = t.lo, t.hi
    if t.integral:
        assert t(str(lo)) == lo and t(str(hi)) == hi and t(f"+{hi}") == hi
        if lo <= 0 <= hi:
            assert t("-0") == 0
        return
    first = math.nextafter(lo, math.inf) if t.lo_open else lo
    assert t(repr(first)) == first and t(repr(float(hi))) == hi and t(f"+{hi!r}") == hi
    if lo <= 0 <= hi and not (t.lo_open and lo == 0):
        for text in ("-0", "-0.0", "-0e5"):
            v = t(text)
            assert v == 0 and math.copysign(1.0, v) == 1.0, text


@pytest.mark.parametrize("prog", ["droid-gmf1-serial", "droid-mvs"])
def test_a_serial_rate_is_a_standard_one(prog, no_run, capsys):
    """--baud inside its range but not a standard rate (termios, pyserial) is refused too."""
    main = cliranges.main_of(prog)
    for value in ("9601", "20000", "3999999"):
        code, err = _call(main, ["mvs" if prog == "droid-mvs" else "gmf1", f"--baud={value}"], capsys)
        assert code == 2 and "standard rates" in err and len(err.strip().splitlines()) == 1, (value, err)
    for value in ("19200", "115200", "4000000"):
        with pytest.raises(_Accepted):
            _call(main, ["mvs" if prog == "droid-mvs" else "gmf1", f"--baud={value}"], capsys)


MOVE_GOOD = ["0", "0", "0", "0", "0", "0", "2"]


@pytest.mark.parametrize("index", [0, 5, 6], ids=["E1", "E6", "SECONDS"])
@pytest.mark.parametrize("mode", ["joint", "cart"])
def test_move_values_refused_before_the_cell_is_contacted(index, mode, tmp_path, cell_name, capsys):
    """droid-move's 7 values: bad ones exit 2 with one line; the cell (not up) is never asked
    (a value that got through would fail with exit 1: the cell is not up)."""
    from droid.tasks.move import main

    cell = make_cell_file(tmp_path, cell_name)
    good = list(MOVE_GOOD) if mode == "joint" else ["300", "100", "1340", "0", "180", "0", "2"]
    bad = MALFORMED + ["1e308", "-1e308", "1.7976931348623157e308", str(10**30), str(-10**30)]
    if index == 6:
        bad += ["-0", "-0.0", "0", "5e-324", "1e-320", repr(math.nextafter(cli.MAX_MOVE_S, math.inf)), "1e9"]
    for value in bad:
        values = good[:index] + [value] + good[index + 1:]
        argv = ["--cell", str(cell), "arm1", mode, "--", *values]
        code, err = _call(main, argv, capsys)
        assert code == 2, (values, err)
        assert "Traceback" not in err, (values, err)
        assert len(err.strip().splitlines()) == 1, (values, err)
    assert cell_objects(cell_name) == []


SUBPROCESS = [  # (console script, argv, words the one line must hold)
    ("droid-snoop", ["arm1", "--rate", "1e-320"], ["--rate", "[0.001, 1000] Hz"]),
    ("droid-seamtrack", ["16", "--length", "1e308"], ["--length", "(0, 10000] mm"]),
    ("droid-calibrate", ["arm1", "--seed=-1"], ["--seed", "[0, 4294967295]"]),
    ("droid-web", ["--port", "65536"], ["--port", "[1, 65535]"]),
    ("droid-record", ["--out", "x.mcap", "--seconds", "1e308"], ["--seconds", "(0, 86400] s"]),
    ("droid-move", ["arm1", "joint", "0", "0", "0", "0", "0", "0", "1e308"], ["SECONDS", "3600"]),
    ("droid-heartbeat", ["--rate", "5e-324"], ["--rate", "[1, 1000] Hz"]),
    ("droid-gmf1-serial", ["gmf1", "--baud", "1"], ["--baud", "[4800, 4000000] baud"]),
]


@pytest.mark.parametrize("prog,argv,words", SUBPROCESS, ids=[f"{p} {' '.join(a)}" for p, a, _ in SUBPROCESS])
def test_console_scripts_print_one_line_and_no_traceback(prog, argv, words, tmp_path, cell_name):
    exe = Path(sys.executable).parent / prog
    if not exe.exists():
        pytest.skip(f"{prog} is not installed next to {sys.executable}")
    cell = make_cell_file(tmp_path, cell_name)
    p = subprocess.run([str(exe), *argv, "--cell", str(cell)], capture_output=True, text=True, timeout=60,
                       cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1, p.stderr
    for w in words:
        assert w in lines[0], p.stderr
    assert p.stdout == ""
    assert cell_objects(cell_name) == []


BENCH = ROOT / "bench"
UNBOUNDED = {"int", "float", "positive_int", "positive_float", "finite_float", "non_negative_int", "integer"}


def test_bench_scripts_take_bounded_numbers():
    """bench/ scripts are for users too: every option's type is one of droid.cli's bounded types
    (found by reading each script's add_argument calls; their parsers are built inside main)."""
    import ast

    scripts = sorted(BENCH.glob("*.py"))
    assert len(scripts) >= 15
    bad = []
    for path in scripts:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add_argument":
                for kw in node.keywords:
                    if kw.arg == "type" and isinstance(kw.value, ast.Name) and kw.value.id in UNBOUNDED:
                        bad.append(f"{path.name}:{node.lineno} type={kw.value.id}")
                    if kw.arg == "type" and isinstance(kw.value, ast.Attribute) and kw.value.attr == "ArgumentParser":
                        bad.append(f"{path.name}:{node.lineno}")
            if isinstance(node, ast.Attribute) and node.attr == "ArgumentParser" and \
                    isinstance(node.value, ast.Name) and node.value.id == "argparse":
                bad.append(f"{path.name}:{node.lineno} argparse.ArgumentParser (use droid.cli's: one line, exit 2)")
    assert not bad, bad


@pytest.mark.parametrize("argv,words", [(["--frames", "1e308"], ["--frames", "not an integer"]),
                                        (["--frames", "10000001"], ["--frames", "[1, 10000000] frames"]),
                                        (["--seed=-1"], ["--seed", "[0, 4294967295]"])])
def test_a_bench_script_refuses_bad_numbers_in_one_line(argv, words, tmp_path):
    p = subprocess.run([sys.executable, str(BENCH / "bench_mvs.py"), *argv], capture_output=True, text=True,
                       timeout=60, cwd=tmp_path)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and all(w in lines[0] for w in words), p.stderr
