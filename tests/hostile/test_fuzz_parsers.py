"""Hostile bytes (issue 8): every parser of serial lines and ZeroMQ frames refuses garbage
with its own documented error, never another exception.  A modest example count
here; bench/fuzz_parsers.py feeds 10^5 lines per parser (docs/benchmarks.md)."""
from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.brain.plumbing import wire
from droid.brain.runtime.names import NameSpaceCore
from droid.brain.plumbing.sensor_line import Garbled, LineReading, SensorClientCore, parse_line
from droid.cli import BadInput
from droid.subunits.gmf1 import karel_wire as kw
from droid.subunits.reis import servo_wire as sw

FUZZ = settings(max_examples=300, deadline=None)
TOKENS = st.sampled_from([b"MOVE", b"JMOVE", b"HOME", b"STAT", b"ACK", b"DONE", b"BUSY", b"ERR", b"IDLE",
                          b"MOVING", b"RANGE", b"invalid", b"0", b"7", b"4294967296", b"1e", b"0x10", b"nan",
                          b"-inf", "１２".encode(), b"\xff", b"3.14159", b"12.345", b",", b" ", b"\t", b"\r",
                          b"\n", b"\x00"])
LINES = st.one_of(st.binary(max_size=160), st.lists(TOKENS, max_size=14).map(b"".join))


@FUZZ
@given(LINES)
def test_sensor_line_never_raises(line):
    r = parse_line(line)
    assert isinstance(r, (LineReading, Garbled))
    if r.valid:
        assert all(math.isfinite(v) for v in (r.x_mm, r.y_mm, r.roll_rad)) and abs(r.roll_rad) <= math.pi + 1e-5


@FUZZ
@given(st.lists(LINES, max_size=30))
def test_sensor_client_core_counts_every_line(chunks):
    core = SensorClientCore()
    for c in chunks:
        core.feed(c)
    assert core.lines == core.valid + core.invalid and core.garbled <= core.invalid


@FUZZ
@given(LINES)
def test_karel_parsers_raise_only_wire_error(line):
    for parse in (kw.parse_request, kw.parse_reply):
        try:
            parse(line)
        except kw.WireError as exc:
            assert exc.code in kw.ERR_CODES and "\n" not in str(exc)


@FUZZ
@given(st.lists(LINES, max_size=30))
def test_gmf1_serial_core_survives_garbage_replies(chunks):
    from droid.subunits.gmf1.serial_core import SerialCore, StatusView

    core = SerialCore(_fanuc())
    view = StatusView(True, np.zeros(6, np.int64))
    for tick, c in enumerate(chunks, 1):
        core.step(tick, None, view, c, True)


@FUZZ
@given(st.lists(LINES, max_size=20))
def test_karel_controller_twin_survives_garbage_requests(lines):
    from droid.sim.gmf1.controller import KarelController

    ctl = KarelController(_fanuc())
    t = 0.0
    for ln in lines:
        ctl.receive(ln + b"\r", t)
        t += (len(ln) + 1) * kw.BITS_PER_BYTE / kw.BAUD + 0.2
        ctl.advance(t)
        ctl.transmit(t)
    assert ctl.model.within_limits(ctl.q_deg)


_FANUC = []


def _fanuc():
    if not _FANUC:
        from droid.kinematics import load_robot

        _FANUC.append(load_robot("fanuc_s400"))
    return _FANUC[0]


@FUZZ
@given(st.text(max_size=200))
def test_mvs_replay_line_raises_only_bad_input(text):
    from droid.subunits.mvs.sensor import parse_frame_line

    try:
        parse_frame_line(text, "fuzz")
    except BadInput as exc:
        assert "\n" not in str(exc)


@FUZZ
@given(st.binary(max_size=80), st.lists(st.binary(max_size=40), max_size=6))
def test_zmq_frame_unpackers_raise_only_their_errors(frame, frames):
    for fn, exc in ((wire.unpack_tick, wire.BadFrame), (sw.unpack_command, sw.BadServoMessage),
                    (sw.unpack_status, sw.BadServoMessage)):
        try:
            fn(frame)
        except exc:
            pass
    for kind in (wire.KIND_CMD, wire.KIND_STA):
        for fs in (frames, [wire.LINK_PROTO, *frames]):
            try:
                wire.unpack_link(fs, kind)
            except wire.BadFrame:
                pass


JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
                    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c, max_size=4),
                    max_leaves=12)


@FUZZ
@given(st.lists(st.fixed_dictionaries({}, optional={
    "op": st.sampled_from(["register", "unregister", "locate", "list", "bogus"]) | JSON,
    "name": st.text(max_size=70) | JSON, "endpoint": st.sampled_from(["tcp://127.0.0.1:1", "ipc:///x"]) | JSON,
    "pid": st.integers() | JSON, "host": st.text(max_size=8) | JSON, "ttl_s": st.floats() | JSON, "id": JSON}),
    max_size=8))
def test_name_space_answers_any_request(reqs):
    """droid-names' core answers every JSON object, and a later list still works (a
    registration with pid 10**30 used to make every later request raise)."""
    core = NameSpaceCore("boot")
    for now, req in enumerate(reqs):
        rep = core.handle(req, now)
        assert isinstance(rep, dict) and isinstance(rep.get("ok"), bool)
    assert core.handle({"op": "list"}, len(reqs))["ok"]
    core.handle({"op": "register", "name": "x", "endpoint": "ipc:///x", "pid": 10 ** 30, "host": "boot"}, 0)
    assert core.handle({"op": "list"}, 1)["ok"]
