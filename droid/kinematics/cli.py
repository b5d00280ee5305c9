"""droid-kin: forward and inverse kinematics of a robot model, for scripts (thesis §4.1.1, §4.1.7).

Usage::

    droid-kin fk --robot NAME [--json] [Q1 .. Q6]
    droid-kin ik --robot NAME [--prev Q1 .. Q6] [--all] [--json] [X Y Z A B C]
    droid-kin robots [--json]
    droid-kin urdf [ROBOT] [--out FILE] [--cell FILE --subunit NAME]
    droid-kin urdf --write-bundled

Joint angles in degrees; X Y Z in mm; A B C are Z-Y-Z Euler angles in
degrees (thesis eq. 4.2).  NAME is a bundled robot (``droid-kin robots``) or
a path to a ``.toml`` robot file.

Output, one record a line:

* ``fk``: plain ``X Y Z A B C`` (the pose, so it can be fed to ``ik``);
  ``--json``: ``{"T": [[4 rows of 4]]}``.
* ``urdf``: the robot file as URDF (:mod:`droid.kinematics.urdf`) on stdout or in
  ``--out FILE``; with ``--cell FILE --subunit NAME`` also the fixed links ``tool`` and
  ``sensor`` of the cell's world-device mounts on that subunit (``tool_pose`` /
  ``sensor_pose``, T_wcp_* in mm and ZYZ deg), and ROBOT defaults to the subunit's robot.
  ``--write-bundled`` (re)writes ``droid/kinematics/robots/urdf/<robot>.urdf`` for every
  bundled robot and prints their paths.
* ``ik``: plain: the picked joint angles ``Q1 .. Q6``; with ``--all`` one line
  ``pick: Q1..Q6 | 0: Q1..Q6 | 1: none | ...``.  ``--json``:
  ``{"solutions": [8 entries, each 6 numbers or null], "pick": [6] or null}``
  (plus ``"error": reason`` when the pose has no commandable solution).

Without angles/pose on the command line, vectors are read from stdin, one a
line (whitespace or comma separated; blank lines and ``#`` comments are
skipped), and one result line is written per vector, in order, flushed per
read chunk.  For ``ik`` a line holds a pose (6 numbers; the previous line's
pick — initially ``--prev``, default all zeros — is the previous joint
vector) or a pose and a previous joint vector (12 numbers).  A line that
fails (malformed, a number outside the command line's range, unreachable or
out of limits) yields an error record
(plain: ``error: line N: reason``; json: ``{"error": ..., "line": N}`` or the
ik object with ``"pick": null``), processing continues, the chain keeps the
last good pick, and the exit code is 2 with a one-line summary on stderr.

Exit codes (droid.cli): 0 ok; 2 bad arguments or input, unknown robot, an
unreachable or out-of-limit target, a robot file that cannot make a valid URDF (one line
naming the key), ``--out`` into a missing directory.
"""
from __future__ import annotations

import argparse
import io
import json
import os
import select
import sys
from typing import Iterator, Sequence

import numpy as np

from droid.cli import ArgumentParser, BadInput, bounded_float, read_toml, run
from droid.kinematics import RobotFileError, list_robots, load_robot
from droid.kinematics.transforms import T_to_pose, pose_to_T
from droid.kinematics.urdf import BUNDLED_URDF_DIR, bundled_urdf_path, robot_urdf
from droid.numbers import BadFile, check_numbers

PROG = "droid-kin"
#: vectors solved per batch in stdin mode.
CHUNK_LINES = 1024
_READ_BYTES = 1 << 16


#: Joint angles [deg] and pose values (mm or deg) a script may give: wide, but bounded so that
#: no value overflows the trigonometry or means nothing (1e308 deg is no angle).
ANGLE_DEG = bounded_float(-3600.0, 3600.0, "deg")
POSE_VALUE = bounded_float(-1e6, 1e6, "(mm or deg)")


def _parser() -> ArgumentParser:
    ap = ArgumentParser(prog=PROG, description="Forward/inverse kinematics of a DROID robot model.")
    sub = ap.add_subparsers(dest="cmd", required=True, parser_class=ArgumentParser)
    fk = sub.add_parser("fk", help="joint angles [deg] -> wrist-centre pose")
    fk.add_argument("--robot", required=True, help="bundled robot name or path to a .toml file")
    fk.add_argument("--json", action="store_true", help='print {"T": [[...]]} records')
    fk.add_argument("q", nargs="*", type=ANGLE_DEG, metavar="Q", help="6 joint angles [deg] (else stdin)")
    ik = sub.add_parser("ik", help="wrist-centre pose -> 8 solutions and the planner's pick")
    ik.add_argument("--robot", required=True, help="bundled robot name or path to a .toml file")
    ik.add_argument("--prev", nargs=6, type=ANGLE_DEG, metavar="Q", help="previous joint angles [deg] (default 0)")
    ik.add_argument("--all", action="store_true", help="also print all 8 solutions")
    ik.add_argument("--json", action="store_true", help="print JSON records")
    ik.add_argument("pose", nargs="*", type=POSE_VALUE, metavar="P", help="X Y Z [mm] A B C [deg ZYZ] (else stdin)")
    rb = sub.add_parser("robots", help="list the bundled robot models")
    rb.add_argument("--json", action="store_true")
    ur = sub.add_parser("urdf", help="print the robot file as URDF (docs/kinematics.md, URDF)")
    ur.add_argument("robot", nargs="?", metavar="ROBOT",
                    help="bundled robot name or path to a .toml file (default with --cell: the subunit's robot)")
    ur.add_argument("--out", metavar="FILE", help="write the URDF here instead of stdout")
    ur.add_argument("--cell", metavar="FILE", help="cell file whose world-device mounts give the tool and sensor")
    ur.add_argument("--subunit", metavar="NAME", help="the cell's subunit carrying the robot (with --cell)")
    ur.add_argument("--write-bundled", action="store_true",
                    help="write droid/kinematics/robots/urdf/<robot>.urdf for every bundled robot")
    return ap


# ---------------------------------------------------------------- formatting


def _num(v: float) -> float:
    return v + 0.0  # -0.0 -> 0.0


def _fmt(values) -> str:
    return " ".join(f"{_num(v):.6f}" for v in values)


def _row_or_none(row) -> list | None:
    if any(v != v for v in row):
        return None
    return [_num(v) for v in row]


def _ik_record(sols: list, pick: list | None, as_json: bool, show_all: bool, error: str | None) -> str:
    if as_json:
        rec = {"solutions": [_row_or_none(s) for s in sols], "pick": None if pick is None else [_num(v) for v in pick]}
        if error is not None:
            rec["error"] = error
        return json.dumps(rec)
    if not show_all:
        return _fmt(pick) if pick is not None else f"error: {error}"
    head = f"pick: {_fmt(pick)}" if pick is not None else "pick: none"
    parts = [head] + [f"{i}: {_fmt(s)}" if s[0] == s[0] else f"{i}: none" for i, s in enumerate(sols)]
    return " | ".join(parts)


def _fk_record(t: np.ndarray, as_json: bool) -> str:
    if as_json:
        return json.dumps({"T": [[_num(v) for v in row] for row in t.tolist()]})
    return _fmt(T_to_pose(t))


def _error_record(lineno: int, reason: str, as_json: bool) -> str:
    if as_json:
        return json.dumps({"error": reason, "line": lineno})
    return f"error: line {lineno}: {reason}"


# ---------------------------------------------------------------- stdin


def _line_chunks(stream, max_lines: int = CHUNK_LINES) -> Iterator[list[str]]:
    """Lines of ``stream`` in chunks: as many as are available now (up to max_lines), so pipes stream."""
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, io.UnsupportedOperation, ValueError):
        fd = None
    if fd is None:
        batch: list[str] = []
        for line in stream:
            batch.append(line)
            if len(batch) >= max_lines:
                yield batch
                batch = []
        if batch:
            yield batch
        return
    buf = b""
    eof = False
    while not eof:
        data = os.read(fd, _READ_BYTES)
        if data:
            buf += data
        else:
            eof = True
        while not eof and buf.count(b"\n") < max_lines:
            ready, _, _ = select.select([fd], [], [], 0)
            if not ready:
                break
            data = os.read(fd, _READ_BYTES)
            if data:
                buf += data
            else:
                eof = True
        lines = buf.split(b"\n")
        buf = lines.pop()
        if eof and buf:
            lines.append(buf)
            buf = b""
        for i in range(0, len(lines), max_lines):
            yield [raw.decode("utf-8", "replace") for raw in lines[i : i + max_lines]]


#: The number types of a stdin line, by position: the command line's ranges (issue 16).
FK_LINE = (ANGLE_DEG,) * 6
IK_LINE = (POSE_VALUE,) * 6 + (ANGLE_DEG,) * 6  # a pose, then optionally the previous joint vector


def _parse_line(text: str, arities: tuple[int, ...], types) -> list[float] | None | str:
    """Numbers on a line, each checked by its position's type; None for a blank/comment line;
    a reason string if malformed or out of range."""
    body = text.split("#", 1)[0].replace(",", " ").split()
    if not body:
        return None
    vals = []
    for i, tok in enumerate(body):
        try:
            v = types[min(i, len(types) - 1)](tok)
        except (ValueError, argparse.ArgumentTypeError) as exc:
            return str(exc)
        vals.append(v)
    if len(vals) not in arities:
        want = " or ".join(str(a) for a in arities)
        return f"expected {want} numbers, got {len(vals)}"
    return vals


class _Failures:
    def __init__(self) -> None:
        self.count = 0
        self.first = ""

    def add(self, lineno: int, reason: str) -> None:
        self.count += 1
        if not self.first:
            self.first = f"line {lineno}: {reason}"


def _emit(lines: list[str]) -> None:
    if lines:
        sys.stdout.write("\n".join(lines) + "\n")
        sys.stdout.flush()


def _stream_fk(model, as_json: bool) -> _Failures:
    fails = _Failures()
    lineno = 0
    for chunk in _line_chunks(sys.stdin):
        items = []  # (lineno, vals | reason)
        for text in chunk:
            lineno += 1
            parsed = _parse_line(text, (6,), FK_LINE)
            if parsed is not None:
                items.append((lineno, parsed))
        good = [vals for _, vals in items if not isinstance(vals, str)]
        ts = model.fk_batch(np.array(good).reshape(-1, 6)) if good else None
        out, k = [], 0
        for n, vals in items:
            if isinstance(vals, str):
                fails.add(n, vals)
                out.append(_error_record(n, vals, as_json))
            else:
                out.append(_fk_record(ts[k], as_json))
                k += 1
        _emit(out)
    return fails


def _stream_ik(model, prev0: list[float], as_json: bool, show_all: bool) -> _Failures:
    fails = _Failures()
    lineno = 0
    prev = list(prev0)
    for chunk in _line_chunks(sys.stdin):
        items = []
        for text in chunk:
            lineno += 1
            parsed = _parse_line(text, (6, 12), IK_LINE)
            if parsed is not None:
                items.append((lineno, parsed))
        good = [vals for _, vals in items if not isinstance(vals, str)]
        if good:
            poses = np.array([v[:6] for v in good])
            hints = np.array([v[6:] if len(v) == 12 else prev for v in good])
            used = np.zeros(len(good), bool)
            sols_all = model.ik_all_batch(pose_to_T(*poses.T), hints, hint_used=used).tolist()
        out, k = [], 0
        for n, vals in items:
            if isinstance(vals, str):
                fails.add(n, vals)
                out.append(_error_record(n, vals, as_json))
                continue
            q_prev = vals[6:] if len(vals) == 12 else prev
            sols = sols_all[k]
            if used[k] and q_prev != list(hints[k]):
                # singular pose: the hint is the actual previous pick (not known when batching)
                sols = model.ik_all(pose_to_T(*vals[:6]), q_prev).tolist()
            k += 1
            i = model.pick_index(sols, q_prev)
            if i < 0:
                reason = model.explain(sols)
                fails.add(n, reason)
                if as_json:
                    rec = json.loads(_ik_record(sols, None, True, show_all, reason))
                    rec["line"] = n
                    out.append(json.dumps(rec))
                else:
                    out.append(f"error: line {n}: {reason}")
                continue
            pick = sols[i]
            prev = list(pick)
            out.append(_ik_record(sols, pick, as_json, show_all, None))
        _emit(out)
    return fails


# ---------------------------------------------------------------- urdf


def cell_mounts(cell: dict, subunit: str, where: str = "cell") -> tuple[str | None, dict]:
    """The robot of ``[subunits.<subunit>]`` and the mounts of the cell's world devices on it.

    A world device mounts a tool (``tool_pose``) or a sensor (``sensor_pose``) on the arm it
    names in ``tool_robot``: the world device whose ``subunit`` is ``subunit`` (or the device
    of that name).  Returns (robot name or None, {"tool": 4x4 mm, "sensor": 4x4 mm} of those
    found).  :class:`BadInput` (one line) for a missing subunit or contradicting mounts.
    """
    subs = cell.get("subunits", {})
    if not isinstance(subs, dict) or not isinstance(subs.get(subunit), dict):
        have = ", ".join(sorted(subs)) if isinstance(subs, dict) else ""
        raise BadInput(f"{where}: no subunit {subunit!r} (subunits: {have or 'none'})")
    robot = subs[subunit].get("robot")
    if robot is not None and not isinstance(robot, str):
        raise BadInput(f"{where}: [subunits.{subunit}] robot: must be a robot name or file")
    world = cell.get("world", {})
    devices = world.get("devices", {}) if isinstance(world, dict) else {}
    if not isinstance(devices, dict):
        devices = {}
    arm_names = {subunit} | {n for n, d in devices.items() if isinstance(d, dict) and d.get("subunit") == subunit}
    mounts: dict = {}
    for kind, key in (("tool", "tool_pose"), ("sensor", "sensor_pose")):
        for dname in sorted(devices):
            dev = devices[dname]
            if not isinstance(dev, dict) or key not in dev or dev.get("tool_robot") not in arm_names:
                continue
            pose = dev[key]
            if not isinstance(pose, list) or len(pose) != 6:
                raise BadInput(f"{where}: [world.devices.{dname}] {key}: expected [x, y, z, A, B, C] (mm, ZYZ deg)")
            T = pose_to_T(*(float(v) for v in pose))
            if kind in mounts and not np.allclose(mounts[kind], T, atol=1e-9):
                raise BadInput(f"{where}: [world.devices.{dname}] {key}: differs from another device's {key} "
                               f"on subunit {subunit!r}")
            mounts[kind] = T
    return robot, mounts


def _write_text(path: str, text: str) -> None:
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise BadInput(f"--out {path}: directory {parent} does not exist")
    if os.path.isdir(path):
        raise BadInput(f"--out {path}: is a directory")
    try:
        with open(path, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
    except OSError as exc:
        raise BadInput(f"--out {path}: cannot write ({exc.strerror or exc})") from None


def _urdf(args) -> int:
    if args.write_bundled:
        if args.robot or args.out or args.cell or args.subunit:
            raise BadInput("urdf --write-bundled takes no ROBOT, --out, --cell or --subunit")
        BUNDLED_URDF_DIR.mkdir(exist_ok=True)
        for name in list_robots():
            path = bundled_urdf_path(name)
            with open(path, "w", encoding="utf-8", newline="\n") as f:
                f.write(robot_urdf(load_robot(name)))
            print(path)
        return 0
    if (args.cell is None) != (args.subunit is None):
        raise BadInput("urdf: give --cell FILE and --subunit NAME together")
    mounts: dict = {}
    robot = args.robot
    if args.cell is not None:
        cell = read_toml(args.cell, "cell")
        try:
            check_numbers(cell)
        except BadFile as exc:
            raise BadInput(f"cell {args.cell}: {exc}") from None
        cell_robot, mounts = cell_mounts(cell, args.subunit, f"cell {args.cell}")
        if robot is None:
            if cell_robot is None:
                raise BadInput(f"cell {args.cell}: [subunits.{args.subunit}] has no robot; give ROBOT")
            robot = cell_robot
        elif cell_robot is not None and _load(robot).name != _load(cell_robot).name:
            raise BadInput(f"urdf: subunit {args.subunit!r} of {args.cell} carries {cell_robot!r}, not {robot!r}")
    if robot is None:
        raise BadInput("urdf: give ROBOT (a bundled name or a .toml file)")
    text = robot_urdf(_load(robot), tool=mounts.get("tool"), sensor=mounts.get("sensor"))
    if args.out is None:
        sys.stdout.write(text)
        sys.stdout.flush()
    else:
        _write_text(args.out, text)
    return 0


# ---------------------------------------------------------------- main


def _load(name: str):
    try:
        return load_robot(name)
    except RobotFileError as exc:
        raise BadInput(str(exc)) from None


def _finish(fails: _Failures) -> int:
    if fails.count:
        raise BadInput(f"{fails.count} input line(s) failed; first: {fails.first}")
    return 0


@run
def main(argv: Sequence[str] | None = None) -> int:
    """droid-kin entry point (see module docstring)."""
    args = _parser().parse_args(argv)
    if args.cmd == "robots":
        for name in list_robots():
            m = load_robot(name)
            if args.json:
                print(json.dumps({"name": name, "assumed": m.assumed, "description": m.description}))
            else:
                print(f"{name}{' (assumed)' if m.assumed else ''}: {m.description}")
        return 0
    if args.cmd == "urdf":
        return _urdf(args)
    model = _load(args.robot)
    if args.cmd == "fk":
        if len(args.q) not in (0, 6):
            raise BadInput(f"fk: expected 6 joint angles, got {len(args.q)}")
        if not args.q:
            return _finish(_stream_fk(model, args.json))
        print(_fk_record(model.fk(args.q), args.json))
        return 0
    # ik
    if len(args.pose) not in (0, 6):
        raise BadInput(f"ik: expected X Y Z A B C (6 numbers), got {len(args.pose)}")
    prev = list(args.prev) if args.prev is not None else [0.0] * 6
    if not args.pose:
        return _finish(_stream_ik(model, prev, args.json, args.all))
    t = pose_to_T(*args.pose)
    sols = model.ik_all(t, prev).tolist()
    i = model.pick_index(sols, prev)
    if i < 0:
        reason = model.explain(sols)
        if args.json:
            print(_ik_record(sols, None, True, args.all, reason))
        raise BadInput(reason)
    print(_ik_record(sols, sols[i], args.json, args.all, None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
