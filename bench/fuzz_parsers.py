#!/usr/bin/env python3
"""Fuzz every parser of serial bytes (and the ZeroMQ frame unpackers) with 10^5 lines each.

A *crash* is any exception other than the parser's documented refusal
(sensor line: none at all, a Garbled result instead; KAREL wire: WireError;
DROID wire: BadFrame; servo messages: BadServoMessage; MVS replay lines:
BadInput).  The stateful consumers are fed the same lines as a byte stream in
random chunks: the Brain's sensor client core (SensorClientCore), the
gmf1 serial program's core reading controller replies (SerialCore), and the
KAREL controller twin reading host requests (KarelController).

Lines are drawn from three sources, a third each: random bytes (0-80),
valid lines of the grammar with 1-4 random byte edits (flip, insert, delete,
duplicate a field), and token soup (grammar words, numbers such as "1e",
"0x10", "nan", "１２", separators, terminators).

Usage: bench/fuzz_parsers.py [--lines 100000] [--seed 8]
Prints one row per parser: lines fed, accepted, refused, crashes (exit 1 if any).
Record the result in docs/benchmarks.md.
"""
from __future__ import annotations

import platform
import random
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from droid.brain.plumbing import wire  # noqa: E402
from droid.brain.plumbing.sensor_line import Garbled, LineReading, SensorClientCore, parse_line  # noqa: E402
from droid.cli import ArgumentParser, BadInput, bounded_int, seed_int  # noqa: E402
from droid.subunits.gmf1 import karel_wire as kw  # noqa: E402
from droid.subunits.reis import servo_wire as sw  # noqa: E402

SENSOR_VALID = [b"12.345,-6.789,0.12345", b"invalid", b"-9999.999,9999.999,-3.14159", b"0.000,0.000,0.00000"]
KAREL_REQUESTS = [b"MOVE 7 300.000 100.000 1340.000 0.000 90.000 0.000 2.000", b"JMOVE 8 0 0 0 0 0 0",
                  b"HOME 9", b"STAT 10", b"MOVE 4294967295 1 2 3 4 5 6"]
KAREL_REPLIES = [b"ACK 7 1.500", b"DONE 7", b"BUSY 7", b"ERR 0 LONG", b"ERR 7 RANGE", b"STAT 10 IDLE 7",
                 b"STAT 11 MOVING 12"]
TOKENS = [b"MOVE", b"JMOVE", b"HOME", b"STAT", b"ACK", b"DONE", b"BUSY", b"ERR", b"IDLE", b"MOVING",
          b"SYNTAX", b"RANGE", b"LONG", b"OVERRUN", b"invalid", b"0", b"1", b"-1", b"4294967296",
          b"99999999999", b"1e", b"1e5", b"0x10", b"nan", b"inf", b"-inf", b"1_000", b".", b"-", b"+",
          "１２".encode(), b"\xff\xfe", b"3.14159", b"-3.14160", b"12.345", b"1.2.3", b",", b" ", b"\t",
          b"\r", b"\n", b"\r\n", b"\x00", b"#"]


def mutate(rng: random.Random, line: bytes) -> bytes:
    b = bytearray(line)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(4)
        i = rng.randrange(len(b) + 1)
        if op == 0 and b and i < len(b):
            b[i] = rng.randrange(256)
        elif op == 1:
            b[i:i] = bytes([rng.randrange(256)])
        elif op == 2 and b and i < len(b):
            del b[i]
        else:
            parts = bytes(b).split(b" ")
            j = rng.randrange(len(parts))
            parts.insert(j, parts[j])
            b = bytearray(b" ".join(parts))
    return bytes(b)


def make_lines(rng: random.Random, n: int, valid: list[bytes]) -> list[bytes]:
    out = []
    for k in range(n):
        kind = k % 3
        if kind == 0:
            out.append(bytes(rng.randrange(256) for _ in range(rng.randrange(81))))
        elif kind == 1:
            out.append(mutate(rng, rng.choice(valid)))
        else:
            out.append(b"".join(rng.choice(TOKENS) + rng.choice([b" ", b"", b","])
                                for _ in range(rng.randrange(1, 10))))
    return out


def chunks(rng: random.Random, lines: list[bytes], end: bytes):
    """The lines as one byte stream, cut into random chunks (1-64 bytes)."""
    stream = end.join(lines) + end
    i = 0
    while i < len(stream):
        j = i + rng.randint(1, 64)
        yield stream[i:j]
        i = j


# -- targets: each returns (accepted, refused); anything else raised is a crash -----------------

def t_sensor_line(rng, lines):
    acc = ref = 0
    for ln in lines:
        r = parse_line(ln)
        if isinstance(r, Garbled):
            ref += 1
        else:
            assert isinstance(r, LineReading)
            if r.valid:
                assert all(np.isfinite([r.x_mm, r.y_mm, r.roll_rad])) and abs(r.roll_rad) <= 3.14160
            acc += 1
    return acc, ref


def t_sensor_client(rng, lines):
    core = SensorClientCore()
    for c in chunks(rng, lines, b"\n"):
        core.feed(c)
    assert core.lines == core.valid + core.invalid and core.garbled <= core.invalid
    return core.valid, core.garbled


def _refusals(fn, exc, lines):
    acc = ref = 0
    for ln in lines:
        try:
            fn(ln)
            acc += 1
        except exc:
            ref += 1
    return acc, ref


def t_karel_request(rng, lines):
    return _refusals(kw.parse_request, kw.WireError, lines)


def t_karel_reply(rng, lines):
    return _refusals(kw.parse_reply, kw.WireError, lines)


def t_karel_splitter(rng, lines):
    sp = kw.LineSplitter()
    n = 0
    for c in chunks(rng, lines, b"\r"):
        for ln in sp.feed(c):
            assert len(ln) <= kw.MAX_LINE + 1
            n += 1
    return n, sp.overlong


def t_gmf1_serial_core(rng, lines):
    """droid-gmf1-serial's core reading controller replies (CR LF lines) from the port."""
    from droid.kinematics import load_robot
    from droid.subunits.gmf1.serial_core import SerialCore, StatusView

    core = SerialCore(load_robot("fanuc_s400"))
    view = StatusView(True, np.zeros(6, np.int64))
    tick = 1
    for c in chunks(rng, lines, b"\r\n"):
        core.step(tick, None, view, c, True)
        tick += 1
    return core.unexpected, core.garbled  # well-formed but unexpected replies, garbled lines


def t_karel_controller(rng, lines):
    """The KAREL controller twin reading host requests (CR lines) from its line."""
    from droid.kinematics import load_robot
    from droid.sim.gmf1.controller import KarelController

    ctl = KarelController(load_robot("fanuc_s400"))
    t = 0.0
    for ln in lines:  # one line per interpreter cycle (6 Hz), so each one is parsed
        ctl.receive(ln + b"\r", t)
        t += (len(ln) + 1) * kw.BITS_PER_BYTE / kw.BAUD + 0.2
        ctl.advance(t)
        ctl.transmit(t)
    return ctl.lines - ctl.errors, ctl.errors


def t_mvs_replay(rng, lines):
    from droid.subunits.mvs.sensor import parse_frame_line

    def parse(ln):
        parse_frame_line(ln.decode("ascii", "replace"), "fuzz")
    return _refusals(parse, BadInput, lines)


def t_heartbeat_frame(rng, lines):
    frames = [ln[:wire.HB_SIZE].ljust(wire.HB_SIZE, b"\0") if k % 2 else ln for k, ln in enumerate(lines)]
    return _refusals(wire.unpack_tick, wire.BadFrame, frames)


def t_link_frames(rng, lines):
    def unpack(ln):
        parts = ln.split(b" ")[:rng.randint(1, 5)]
        if rng.random() < 0.5:
            parts[0:1] = [wire.LINK_PROTO]
        wire.unpack_link(parts, wire.KIND_CMD)
    return _refusals(unpack, wire.BadFrame, lines)


def t_servo_messages(rng, lines):
    acc = ref = 0
    for ln in lines:
        for fn in (sw.unpack_command, sw.unpack_status):
            try:
                fn(ln)
                acc += 1
            except sw.BadServoMessage:
                ref += 1
    return acc, ref


TARGETS = [  # (name, target, valid lines to mutate)
    ("sensor line parse_line (Brain <- MVS/tool)", t_sensor_line, SENSOR_VALID),
    ("sensor SensorClientCore.feed (stream)", t_sensor_client, SENSOR_VALID),
    ("KAREL parse_request (controller <- host)", t_karel_request, KAREL_REQUESTS),
    ("KAREL parse_reply (host <- controller)", t_karel_reply, KAREL_REPLIES),
    ("KAREL LineSplitter (stream)", t_karel_splitter, KAREL_REQUESTS + KAREL_REPLIES),
    ("gmf1 SerialCore.step rx (stream)", t_gmf1_serial_core, KAREL_REPLIES),
    ("KAREL controller twin receive (per cycle)", t_karel_controller, KAREL_REQUESTS),
    ("MVS replay parse_frame_line", t_mvs_replay, [b" ".join([b"120"] * 240)]),
    ("heartbeat unpack_tick (ZeroMQ)", t_heartbeat_frame, [wire.pack_tick(wire.Tick(5, 1, 2, 0))]),
    ("link unpack_link (ZeroMQ)", t_link_frames, [b" ".join(wire.pack_link(wire.KIND_CMD, 3, b"x"))]),
    ("servo unpack_command/status (ZeroMQ)", t_servo_messages, [b"\0" * 64]),
]


def run(n_lines: int, seed: int, names: list[str] | None = None, out=sys.stdout) -> int:
    crashes = 0
    print(f"# fuzz_parsers: {n_lines} lines per parser, seed {seed}, Python {platform.python_version()}, "
          f"{platform.machine()}", file=out)
    print(f"{'parser':<46} {'lines':>7} {'accepted':>9} {'refused':>8} {'crashes':>8} {'s':>6}", file=out)
    for name, fn, valid in TARGETS:
        if names and not any(n in name for n in names):
            continue
        rng = random.Random(f"{seed}:{name}")
        lines = make_lines(rng, n_lines, valid)
        t0 = time.perf_counter()
        try:
            acc, ref = fn(rng, lines)
            crash = ""
        except Exception as exc:  # noqa: BLE001 (that is the point: report it)
            acc = ref = 0
            crash = f"{type(exc).__name__}: {exc}"
        dt = time.perf_counter() - t0
        crashes += bool(crash)
        print(f"{name:<46} {n_lines:>7} {acc:>9} {ref:>8} {int(bool(crash)):>8} {dt:>6.1f}", file=out)
        if crash:
            print(f"   CRASH {crash[:200]}", file=out)
    print(f"# {'no crash' if not crashes else f'{crashes} parser(s) crashed'}", file=out)
    return 1 if crashes else 0


def main() -> int:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=bounded_int(1, 10**9, "lines"), default=100_000,
                    help="lines per parser (default 10^5)")
    ap.add_argument("--seed", type=seed_int, default=8, help="random seed")
    ap.add_argument("--only", action="append", help="run parsers whose name contains this")
    args = ap.parse_args()
    return run(args.lines, args.seed, args.only)


if __name__ == "__main__":
    sys.exit(main())
