"""The KAREL serial grammar: formatting, parsing both directions, line splitting (hypothesis)."""
import math

import pytest
from hypothesis import given, settings, strategies as st

from droid.subunits.gmf1 import karel_wire as kw

ids = st.integers(1, kw.MAX_ID)
mm = st.floats(-5000, 5000, allow_nan=False)
deg = st.floats(-180, 180, allow_nan=False)


@given(ids, st.tuples(mm, mm, mm, deg, deg, deg), st.one_of(st.none(), st.floats(0, 600)))
def test_move_round_trip(cmd_id, pose, dur):
    line = kw.format_move(cmd_id, pose, dur)
    assert line.endswith(b"\r") and len(line) - 1 <= kw.MAX_LINE
    req = kw.parse_request(line[:-1])
    assert req.verb == kw.MOVE and req.cmd_id == cmd_id
    assert all(abs(a - b) <= 0.0005 + 1e-9 for a, b in zip(req.values, pose))
    assert (req.duration_s is None) == (dur is None)
    if dur is not None:
        assert abs(req.duration_s - dur) <= 0.0005 + 1e-9


@given(ids, st.lists(deg, min_size=6, max_size=6))
def test_jmove_home_stat_round_trip(cmd_id, q):
    assert kw.parse_request(kw.format_jmove(cmd_id, q)[:-1]).values == pytest.approx(q, abs=6e-4)
    assert kw.parse_request(kw.format_home(cmd_id)[:-1]) == kw.Request(kw.HOME, cmd_id)
    assert kw.parse_request(kw.format_stat(cmd_id)[:-1]) == kw.Request(kw.STAT, cmd_id)


@given(ids, st.floats(0, 3600), st.sampled_from(kw.ERR_CODES), st.sampled_from(kw.STATES),
       st.integers(0, kw.MAX_ID))
def test_reply_round_trip(cmd_id, secs, code, state, mid):
    for r in (kw.Reply(kw.ACK, cmd_id, seconds=round(secs, 3)), kw.Reply(kw.DONE, cmd_id),
              kw.Reply(kw.BUSY, cmd_id), kw.Reply(kw.ERR, cmd_id, code=code),
              kw.Reply(kw.STAT, cmd_id, state=state, motion_id=mid)):
        raw = kw.format_reply(r)
        assert raw.endswith(b"\r\n")
        assert kw.parse_reply(raw[:-2]) == r


def test_whitespace_and_tabs_are_separators():
    req = kw.parse_request(b"  MOVE\t7   1 2 3\t4 5 6   ")
    assert req.values == (1, 2, 3, 4, 5, 6) and req.duration_s is None


@pytest.mark.parametrize("line, code", [
    (b"", kw.ERR_SYNTAX),
    (b"MOVE", kw.ERR_SYNTAX),
    (b"MOVE 0 1 2 3 4 5 6", kw.ERR_SYNTAX),          # id 0 is reserved
    (b"MOVE 1 1 2 3 4 5", kw.ERR_SYNTAX),            # 5 values
    (b"MOVE 1 1 2 3 4 5 nan", kw.ERR_SYNTAX),
    (b"MOVE 1 1 2 3 4 5 1e3", kw.ERR_SYNTAX),        # no exponents
    (b"MOVE 1 1 2 3 4 5 6 -1", kw.ERR_SYNTAX),       # negative duration
    (b"MOVE 1 1e9 2 3 4 5 6", kw.ERR_SYNTAX),
    (b"MOVE 1 200000 2 3 4 5 6", kw.ERR_RANGE),
    (b"HOME 3 4", kw.ERR_SYNTAX),
    (b"FLY 3", kw.ERR_SYNTAX),
    (b"MOVE 99999999999 1 2 3 4 5 6", kw.ERR_SYNTAX),
    (b"X" * (kw.MAX_LINE + 1), kw.ERR_LONG),
])
def test_bad_requests(line, code):
    with pytest.raises(kw.WireError) as e:
        kw.parse_request(line)
    assert e.value.code == code


def test_bad_request_keeps_the_id_when_readable():
    with pytest.raises(kw.WireError) as e:
        kw.parse_request(b"MOVE 42 1 2 3")
    assert e.value.cmd_id == 42


@pytest.mark.parametrize("line", [b"ACK", b"ACK 5", b"ACK 5 x", b"DONE 5 6", b"ERR 5 WHAT", b"STAT 5 IDLE",
                                  b"STAT 5 SLEEPING 3", b"HELLO 5", b"DONE -5", b"\xff\xfe 5"])
def test_bad_replies(line):
    with pytest.raises(kw.WireError):
        kw.parse_reply(line)


@settings(max_examples=400)
@given(st.binary(max_size=200))
def test_request_parser_takes_any_bytes(data):
    """Controller side: random bytes give a Request or a WireError with a known code, nothing else."""
    try:
        req = kw.parse_request(data)
    except kw.WireError as exc:
        assert exc.code in kw.ERR_CODES and 0 <= exc.cmd_id <= kw.MAX_ID
        return
    assert req.verb in kw.VERBS and 1 <= req.cmd_id <= kw.MAX_ID
    assert all(math.isfinite(v) for v in req.values)


@settings(max_examples=400)
@given(st.binary(max_size=200))
def test_reply_parser_takes_any_bytes(data):
    """Program side: random bytes give a Reply or a WireError, nothing else."""
    try:
        r = kw.parse_reply(data)
    except kw.WireError:
        return
    assert r.kind in kw.REPLY_KINDS and math.isfinite(r.seconds)


@given(st.lists(st.binary(min_size=0, max_size=30), max_size=20), st.data())
def test_splitter_is_independent_of_chunking(pieces, data):
    stream = b"".join(pieces)
    whole = kw.LineSplitter().feed(stream)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    sp = kw.LineSplitter()
    got = []
    prev = 0
    for c in cuts + [len(stream)]:
        got += sp.feed(stream[prev:c])
        prev = c
    assert got == whole
    assert all(b"\r" not in ln and b"\n" not in ln and ln for ln in got)


def test_splitter_cuts_overlong_lines():
    sp = kw.LineSplitter()
    out = sp.feed(b"A" * 300)
    out += sp.feed(b"B" * 50 + b"\r\nDONE 1\r\n")
    assert len(out) == 2 and len(out[0]) == kw.MAX_LINE + 1 and out[1] == b"DONE 1"
    assert sp.overlong == 1
    with pytest.raises(kw.WireError) as e:
        kw.parse_request(out[0])
    assert e.value.code == kw.ERR_LONG


def test_formatting_refuses_nonsense():
    with pytest.raises(ValueError):
        kw.format_move(0, [0] * 6)
    with pytest.raises(ValueError):
        kw.format_move(1, [float("nan")] + [0] * 5)
    with pytest.raises(ValueError):
        kw.format_jmove(1, [0] * 5)
