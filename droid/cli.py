"""Command-line conventions shared by every DROID program (docs/design.md §6).

Exit codes:
  0  success
  2  bad arguments, bad input, an unreachable or out-of-limit target
     (a one-line reason on stderr; nothing moves)
  1  runtime failure (cell not up, subunit stale, timeout)
  130 interrupted by SIGINT

Every program's ``main(argv=None) -> int`` is wrapped with :func:`run`, so a
:class:`BadInput` or :class:`RuntimeFailure` raised anywhere becomes a one-line
message ``prog: reason`` and the right exit code, never a traceback.
"""
from __future__ import annotations

import argparse
import functools
import ipaddress
import math
import os
import re
import sys
from typing import Callable, Sequence

from droid.numbers import BadFile, NumberError, Range, baud_range

EXIT_OK = 0
EXIT_RUNTIME = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


#: Modules imported only where a program draws a figure -> the pip name that installs them.
#: A program that finds one missing ends with one line naming it (:func:`run`).
OPTIONAL_MODULES = {"matplotlib": "matplotlib"}


class DroidError(Exception):
    """Base of errors that end a program with a one-line message."""

    exit_code = EXIT_RUNTIME


class BadInput(DroidError):
    """Bad arguments, malformed files or frames, unreachable or out-of-limit targets."""

    exit_code = EXIT_BAD_INPUT


class RuntimeFailure(DroidError):
    """The cell is not up, a subunit is stale, a wait timed out."""

    exit_code = EXIT_RUNTIME


def open_input(path, what: str = "", error: type[DroidError] = BadInput, *, missing: str = "not found"):
    """``path`` opened for reading (binary); ``error`` with one line ``<what> <path>: <why>`` when it
    is missing (``missing``), a directory or unreadable.  The one place input files are opened."""
    name = f"{what} {os.fspath(path)}" if what else os.fspath(path)
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise error(f"{name}: {missing}") from None
    except IsADirectoryError:
        raise error(f"{name}: is a directory") from None
    except OSError as exc:
        raise error(f"{name}: cannot read ({exc.strerror or exc})") from None


def read_toml(path, what: str) -> dict:
    """A TOML file (cell, layout, plan, workpiece, calibration, ...) as a dict; :class:`BadInput`
    ``<what> <path>: <why>`` when it is missing, a directory, unreadable, not UTF-8 or not TOML.
    (droid.kinematics reads robot files itself: it imports nothing else of droid, docs/design.md §7.)"""
    import tomllib

    with open_input(path, what) as f:
        try:
            return tomllib.load(f)
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise BadInput(f"{what} {os.fspath(path)}: not valid TOML ({exc})") from None



class TableReader:
    """Typed, key-checked reading of one TOML table (a cell file's, a device's options).

    Every refusal is one :class:`BadInput` line that starts with ``where`` (the file and the
    table) and names the key.  With ``finite_floats`` a float value must also be finite."""

    def __init__(self, where: str, table: dict, *, finite_floats: bool = False) -> None:
        self.where, self.table, self.finite_floats = where, table, finite_floats
        self.used: set[str] = set()

    def get(self, key: str, typ: type | tuple, default=..., *, check=None):
        """The value of ``key``, of type ``typ`` (an int is taken as a float; a bool is never a
        number); ``default`` when absent (without one, a missing key is refused); ``check(value)``
        returns a reason to refuse it, or None."""
        self.used.add(key)
        if key not in self.table:
            if default is ...:
                raise BadInput(f"{self.where} is missing '{key}'")
            return default
        val = self.table[key]
        if typ is float and isinstance(val, int) and not isinstance(val, bool):
            val = float(val)
        if not isinstance(val, typ) or (typ is int and isinstance(val, bool)):
            tname = typ.__name__ if isinstance(typ, type) else "/".join(t.__name__ for t in typ)
            raise BadInput(f"{self.where} {key} must be {tname}, got {val!r}")
        if self.finite_floats and typ is float and not math.isfinite(val):
            raise BadInput(f"{self.where} {key} must be finite, got {val!r}")
        if check is not None:
            msg = check(val)
            if msg:
                raise BadInput(f"{self.where} {key}: {msg}")
        return val

    def unused(self) -> list[str]:
        """The table's keys no :meth:`get` asked for, sorted."""
        return sorted(k for k in self.table if k not in self.used)


def droid_version() -> str:
    """The installed package's version (its metadata), else ``droid.__version__``."""
    try:
        from importlib.metadata import PackageNotFoundError, version
        try:
            return version("droid")
        except PackageNotFoundError:
            pass
    except ImportError:  # pragma: no cover
        pass
    from droid import __version__
    return __version__


class _VersionAction(argparse.Action):
    """``--version``: print ``PROG VERSION`` and exit 0 (the version looked up only then)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog} {droid_version()}", file=sys.stdout, flush=True)
        parser.exit(EXIT_OK)


class _RangeHelpFormatter(argparse.HelpFormatter):
    """--help states every bounded number's range with its unit: ``...; range (0, 1000] Hz``
    (the range comes from the argument's type, :func:`bounded_float` / :func:`bounded_int`,
    so the rule and its description are written once)."""

    def _get_help_string(self, action):
        text = action.help or ""
        span = getattr(action.type, "span", None)
        if span and span not in text:
            text = f"{text}; range {span}" if text else f"range {span}"
        return text


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error and exit code 2 (never the usage block).

    Every parser answers ``--version`` (``PROG VERSION`` on stdout, exit 0),
    so every console script does (issue 15), unless built with
    ``version=False``.
    """

    def __init__(self, *args, version: bool = True, **kwargs) -> None:
        kwargs.setdefault("formatter_class", _RangeHelpFormatter)
        super().__init__(*args, **kwargs)
        if version and self.add_help:
            self.add_argument("--version", action=_VersionAction, help="print the program's version and exit")

    def _get_values(self, action, arg_strings):
        # Python 3.11's argparse drops a '--' given as an option's value ("--timeout=--") and
        # stores [] as the value, which a program then trips over; 3.12 keeps it as the value.
        if action.option_strings and action.nargs is None and arg_strings == ["--"]:
            value = self._get_value(action, "--")
            self._check_value(action, value)
            return value
        return super()._get_values(action, arg_strings)

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see --help)\n")


# Plain ASCII decimals only.  Python's float() and int() also take "１２" (other
# scripts' digits), "1_000", " 12 ", "infinity": a shell script never means those.
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)
_INTEGER = re.compile(r"[+-]?[0-9]+", re.ASCII)
_NON_FINITE = re.compile(r"[+-]?(?:nan|inf|infinity)", re.ASCII | re.IGNORECASE)


def parse_finite(text: str) -> float:
    """A finite number written as a plain ASCII decimal (optional sign, point, exponent).

    Raises ValueError with a one-line reason: ``not a finite number`` for
    nan/inf or an overflow such as 1e999, ``not a number`` for anything else."""
    if _NON_FINITE.fullmatch(text):
        raise ValueError(f"not a finite number: {text!r}")
    if not _DECIMAL.fullmatch(text):
        raise ValueError(f"not a number: {text!r}")
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"not a finite number: {text!r}")
    return value


def parse_int(text: str) -> int:
    """An integer written in plain ASCII decimal digits (optional sign); ValueError otherwise."""
    if not _INTEGER.fullmatch(text):
        raise ValueError(f"not an integer: {text!r}")
    return int(text, 10)


def finite_float(text: str) -> float:
    """argparse type: a finite float (rejects nan, inf and malformed numbers)."""
    try:
        return parse_finite(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def positive_float(text: str) -> float:
    """argparse type: a finite float > 0."""
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0: {text!r}")
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer > 0."""
    try:
        value = parse_int(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0: {text!r}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0 (plain ASCII decimal digits)."""
    value = integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0: {text!r}")
    return value


def integer(text: str) -> int:
    """argparse type: an integer (plain ASCII decimal digits)."""
    try:
        return parse_int(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def bounded_float(lo: float, hi: float, unit: str = "", *, lo_open: bool = False) -> Callable[[str], float]:
    """argparse type: a finite float in [lo, hi] (``lo_open``: in (lo, hi]); the message names the range.

    Negative zero is zero.  Every duration, rate and size a program accepts has a
    stated maximum, so no accepted value overflows what the program does with it
    (ticks in an int32 field, a deadline, a sleep)."""
    rng = Range(lo, hi, unit, lo_open=lo_open)
    span, u = rng.span, f" {unit}" if unit else ""
    rule = f"must be {'>' if lo_open else '>='} {lo:g} and <= {hi:g}{u}"

    def parse(text: str) -> float:
        value = finite_float(text) + 0.0  # -0.0 -> 0.0
        if not ((lo < value) if lo_open else (lo <= value)) or value > hi:
            raise argparse.ArgumentTypeError(f"{rule}: {text!r} is outside {span}")
        return value

    return _ranged(parse, f"number in {span}", rng)


def bounded_int(lo: int, hi: int, unit: str = "") -> Callable[[str], int]:
    """argparse type: a plain decimal integer in [lo, hi]; the message names the range."""
    rng = Range(lo, hi, unit, integral=True)
    span, u = rng.span, f" {unit}" if unit else ""
    rule = f"must be {'> 0' if lo == 1 else f'>= {lo}'} and <= {hi}{u}"

    def parse(text: str) -> int:
        value = integer(text)
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{rule}: {text!r} is outside {span}")
        return value

    return _ranged(parse, f"integer in [{lo}, {hi}]", rng)


def baud_rate(lo: int) -> Callable[[str], int]:
    """argparse type: a standard serial rate (:data:`droid.numbers.STANDARD_BAUDS`, what pyserial
    and termios take) from ``lo`` to 4 000 000 baud; the same rule as a file's ``baud`` key
    (:func:`droid.numbers.baud_range`)."""
    rng = baud_range(lo)

    def parse(text: str) -> int:
        value = integer(text)
        why = rng.reason(value)
        if why:
            raise argparse.ArgumentTypeError(f"{text!r} {why}")
        return value

    return _ranged(parse, f"serial rate in {rng.span}", rng)


def _ranged(parse, name: str, rng: Range):
    """``parse``, an argparse type, named ``name`` (argparse's messages) and carrying ``rng``: its
    span, bounds, unit and integral flag for the help (:class:`_RangeHelpFormatter`) and the range
    itself for :func:`file_number` (a file's key and the option of the same quantity: one rule)."""
    parse.__name__ = name
    parse.span, parse.lo, parse.hi, parse.lo_open, parse.unit, parse.integral = (
        rng.span, rng.lo, rng.hi, rng.lo_open, rng.unit, rng.integral)
    parse.range = rng
    return parse


def file_number(value, kind, where: str, key: str):
    """A number read from a file (cell, layout, workpiece, plan), checked against ``kind`` -- a
    :class:`droid.numbers.Range` or one of this module's bounded argparse types (the option of
    the same quantity: one rule); :class:`BadInput` ``<where> <key> = <value>: <why> <range>``
    (one line naming the file and the key) otherwise.  Returns the number (floats as float)."""
    rng = getattr(kind, "range", kind)
    try:
        return rng.check(value, key)
    except NumberError as exc:
        raise BadInput(f"{where} {exc}") from None


#: The longest wait any program accepts (--timeout, move times) [s]: one day.
MAX_WAIT_S = 86400.0
#: The longest move a task accepts [s] (droid-move SECONDS): one hour at the
#: heartbeat rate is 216 000 ticks, well inside the Command's int32 tick count.
MAX_MOVE_S = 3600.0
#: Random seeds: what numpy's and the world's generators take (uint32).
MAX_SEED = 2**32 - 1
seed_int = bounded_int(0, MAX_SEED)
#: TCP ports.
tcp_port = bounded_int(1, 65535)


def duration_s(max_s: float = MAX_WAIT_S) -> Callable[[str], float]:
    """argparse type: a duration in (0, ``max_s``] seconds (issue 16: any duration the CLI
    accepts is carried out; one that is not finite, <= 0 or above the maximum is refused).
    A positive subnormal such as 1e-320 s is accepted: a wait that ends at once."""
    return bounded_float(0.0, max_s, "s", lo_open=True)


#: --timeout of every program: (0, one day] s.
timeout_s = duration_s()


def rate_hz(lo: float, hi: float) -> Callable[[str], float]:
    """argparse type: a rate in [``lo``, ``hi``] Hz, ``lo`` > 0: its period 1/rate is finite and
    fits the timers (1e-320 Hz would be a period of inf s)."""
    if not lo > 0:
        raise ValueError(f"a rate's lower limit must be > 0 Hz, got {lo!r}")
    return bounded_float(lo, hi, "Hz")


def is_loopback(host: str) -> bool:
    """``host`` (a name or an address) is this machine's loopback: the servers that show a cell
    (droid-web, droid-foxglove) bind nothing else without a token."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def run(main: Callable[[Sequence[str] | None], int | None]) -> Callable[..., int]:
    """Wrap a ``main(argv)`` so DroidErrors become one-line messages and exit codes."""

    @functools.wraps(main)
    def wrapper(argv: Sequence[str] | None = None) -> int:
        prog = getattr(sys.modules.get(main.__module__), "PROG", None) or os.path.basename(sys.argv[0])
        try:
            code = main(argv)
        except DroidError as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            return exc.exit_code
        except BadFile as exc:  # a robot file's RobotFileError (droid.kinematics raises no BadInput)
            print(f"{prog}: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        except ModuleNotFoundError as exc:
            # an optional module a figure path imports late (matplotlib): one line, never a traceback
            if (exc.name or "").split(".")[0] not in OPTIONAL_MODULES:
                raise
            top = exc.name.split(".")[0]
            print(f"{prog}: {top} is not installed (pip install {OPTIONAL_MODULES[top]}): "
                  "no figure", file=sys.stderr)
            return EXIT_RUNTIME
        except KeyboardInterrupt:
            return EXIT_INTERRUPTED
        except BrokenPipeError:
            # stdout closed by a pipeline consumer (e.g. `| head`): not an error.
            try:
                sys.stdout = open(os.devnull, "w")
            except OSError:
                pass
            return EXIT_OK
        return EXIT_OK if code is None else int(code)

    return wrapper


def entry(main: Callable[..., int]) -> None:
    """Console-script entry: run ``main`` and exit with its code."""
    sys.exit(main())
