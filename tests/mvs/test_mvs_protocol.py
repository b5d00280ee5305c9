"""The serial line grammar, splitter and Brain-side client core."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.subunits.mvs.protocol import (INVALID, Garbled, LineSplitter, Reading, SensorClientCore,
                                         format_line, parse_line, seam_transform)
from droid.subunits.mvs.wire import MAX_LINE_BYTES

# An independent statement of the grammar (docs/mvs.md) to judge the parser by.
MM = r"-?\d{1,4}\.\d{3}"
GRAMMAR = re.compile(rf"{MM},{MM},-?\d\.\d{{5}}\r?")


def grammar_ok(line: bytes) -> bool:
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError:
        return False
    if not GRAMMAR.fullmatch(text) or not text.isascii():
        return False
    return abs(float(text.rstrip("\r").split(",")[2])) <= 3.14159


mm = st.floats(-9999.49, 9999.49, allow_nan=False)
rad = st.floats(-math.pi, math.pi, allow_nan=False)


@given(x=mm, y=mm, roll=rad)
def test_format_then_parse_round_trips(x, y, roll):
    line = format_line(Reading(True, x, y, roll))
    assert line.endswith(b"\n") and len(line) <= MAX_LINE_BYTES
    got = parse_line(line)
    assert isinstance(got, Reading) and got.valid
    assert (got.x_mm, got.y_mm, got.roll_rad) == pytest.approx((x, y, roll), abs=1e-5 + 5e-4)
    assert grammar_ok(line[:-1])


def test_invalid_line():
    assert format_line(None) == b"invalid\n"
    assert parse_line(b"invalid\n") == INVALID == Reading(False, 0.0, 0.0, 0.0)
    assert parse_line(b"invalid\r\n") == INVALID


@pytest.mark.parametrize("x,y,roll", [(math.nan, 0, 0), (0, math.inf, 0), (10000.0, 0, 0), (0, 0, 3.2)])
def test_unsendable_features_go_as_invalid(x, y, roll):
    assert format_line(Reading(True, x, y, roll)) == b"invalid\n"


@pytest.mark.parametrize("line", [
    b"", b"1.000,2.000", b"1.0,2.000,0.10000", b"1.000,2.000,0.1000", b"+1.000,2.000,0.10000",
    b"1.000, 2.000,0.10000", b"1.000,2.000,3.14160", b"12345.000,0.000,0.00000", b"INVALID",
    b"1.000,2.000,0.10000,", b"\xff\xfe", b"1.000,2.000,0.10000\x00",
])
def test_lines_off_the_grammar_are_garbled(line):
    got = parse_line(line)
    assert isinstance(got, Garbled) and not got.valid


@settings(max_examples=500)
@given(st.binary(max_size=64))
def test_random_bytes_never_raise_and_valid_only_if_grammatical(data):
    got = parse_line(data)
    assert isinstance(got, (Reading, Garbled))
    if got.valid:
        body = data[:-1] if data.endswith(b"\n") else data
        assert grammar_ok(body)


@settings(max_examples=300)
@given(st.lists(st.binary(max_size=40).filter(lambda b: b"\n" not in b), max_size=20),
       st.lists(st.integers(0, 2000), max_size=10))
def test_splitter_yields_the_same_lines_however_the_stream_is_cut(lines, cuts):
    stream = b"".join(line + b"\n" for line in lines)
    splitter = LineSplitter()
    got = []
    start = 0
    for cut in sorted({c % (len(stream) + 1) for c in cuts}) + [len(stream)]:
        got += splitter.feed(stream[start:cut])
        start = cut
    expected = [line if len(line) <= MAX_LINE_BYTES else line[:MAX_LINE_BYTES + 1] for line in lines]
    assert got == expected
    assert splitter.overlong == sum(len(line) > MAX_LINE_BYTES for line in lines)


@settings(max_examples=200)
@given(st.lists(st.binary(max_size=300), max_size=30))
def test_splitter_buffer_stays_bounded(chunks):
    splitter = LineSplitter()
    for chunk in chunks:
        for line in splitter.feed(chunk):
            assert len(line) <= MAX_LINE_BYTES + 1
        assert len(splitter._buffer) <= MAX_LINE_BYTES + 1


def test_client_core_returns_the_newest_reading_and_counts():
    core = SensorClientCore(stale_after_feeds=2)
    assert core.feed(b"") == INVALID  # nothing yet
    r = core.feed(b"1.000,2.000,0.10000\n3.000,-4.000,-0.20000\n5.0")
    assert r == Reading(True, 3.0, -4.0, -0.2)
    assert core.feed(b"00,6.000,0.00000\n") == Reading(True, 5.0, 6.0, 0.0)
    assert core.feed(b"invalid\n") == INVALID
    assert core.feed(b"garbage\n") == INVALID
    assert core.feed(b"x" * 500 + b"\n") == INVALID
    assert (core.lines, core.valid, core.invalid, core.garbled) == (6, 3, 3, 2)
    assert core.feed(b"1.000,1.000,0.00000\n").valid
    # Stale: more than 2 feeds without a complete line -> invalid, then fresh again.
    assert core.feed(b"").valid and core.feed(b"").valid
    assert not core.feed(b"").valid and core.stale
    assert core.feed(b"1.500,1.000,0.00000\n").x_mm == 1.5 and not core.stale


@settings(max_examples=300)
@given(st.lists(st.binary(max_size=80), max_size=20))
def test_client_core_never_raises_and_garbage_is_never_valid(chunks):
    core = SensorClientCore()
    for chunk in chunks:
        got = core.feed(chunk)
        if got.valid:
            assert any(grammar_ok(line) for line in b"".join(chunks).replace(b"\r", b"").split(b"\n"))
    assert core.lines == core.valid + core.invalid


def test_seam_transform_is_table_3_3_record():
    t = Reading(True, 1.5, -2.0, 0.3).transform()
    assert t[0:3, 3] == pytest.approx([1.5, -2.0, 0.0])
    assert t[0:3, 0:3] @ [0, 1, 0] == pytest.approx([-math.sin(0.3), math.cos(0.3), 0])  # along the surface
    assert t[0:3, 0:3] @ [0, 0, 1] == pytest.approx([0, 0, 1])  # still along the travel direction
    assert np.allclose(seam_transform(0, 0, 0), np.eye(4))
