"""The serial line grammar, splitter and Brain-side client core."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.subunits.mvs.protocol import (INVALID, Garbled, LineSplitter, LineReading, SensorClientCore,
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
    line = format_line(LineReading(True, x, y, roll))
    assert line.endswith(b"\n") and len(line) <= MAX_LINE_BYTES
    got = parse_line(line)
    assert isinstance(got, LineReading) and got.valid
    assert (got.x_mm, got.y_mm, got.roll_rad) == pytest.approx((x, y, roll), abs=1e-5 + 5e-4)
    assert grammar_ok(line[:-1])


def test_invalid_line():
    assert format_line(None) == b"invalid\n"
    assert parse_line(b"invalid\n") == INVALID == LineReading(False, 0.0, 0.0, 0.0)
    assert parse_line(b"invalid\r\n") == INVALID


@pytest.mark.parametrize("x,y,roll", [(math.nan, 0, 0), (0, math.inf, 0), (10000.0, 0, 0), (0, 0, 3.2)])
def test_unsendable_features_go_as_invalid(x, y, roll):
    assert format_line(LineReading(True, x, y, roll)) == b"invalid\n"


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
    assert isinstance(got, (LineReading, Garbled))
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
    assert r == LineReading(True, 3.0, -4.0, -0.2)
    assert core.feed(b"00,6.000,0.00000\n") == LineReading(True, 5.0, 6.0, 0.0)
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
    t = LineReading(True, 1.5, -2.0, 0.3).transform()
    assert t[0:3, 3] == pytest.approx([1.5, -2.0, 0.0])
    assert t[0:3, 0:3] @ [0, 1, 0] == pytest.approx([-math.sin(0.3), math.cos(0.3), 0])  # along the surface
    assert t[0:3, 0:3] @ [0, 0, 1] == pytest.approx([0, 0, 1])  # still along the travel direction
    assert np.allclose(seam_transform(0, 0, 0), np.eye(4))


# -- capture stamps (issue 12 item 2) ------------------------------------------------------

def test_a_stamped_line_round_trips_and_a_plain_thesis_line_still_parses():
    from droid.brain.plumbing.sensor_line import LineReading, format_line, parse_line, stamp_ms_of

    f = LineReading(True, -1.25, 3.5, 0.01)
    line = format_line(f, stamp_ms_of(123_456_789_000_000))
    assert line == b"-1.250,3.500,0.01000,56789\n" and len(line) <= MAX_LINE_BYTES
    r = parse_line(line)
    assert (r.x_mm, r.y_mm, r.roll_rad, r.stamp_ms) == (-1.25, 3.5, 0.01, 56789)
    plain = parse_line(b"-1.250,3.500,0.01000")
    assert plain.valid and plain.stamp_ms is None
    for bad in (b"1.000,2.000,0.00000,", b"1.000,2.000,0.00000,123456", b"1.000,2.000,0.00000,-5",
                b"1.000,2.000,0.00000,1.5", b"1.000,2.000,0.00000,12,3"):
        assert not parse_line(bad).valid, bad


def test_stamps_from_the_future_too_old_or_out_of_order_are_dropped_and_counted():
    from droid.brain.plumbing.sensor_line import SensorClientCore, format_line, stamp_ms_of
    from droid.brain.plumbing.sensor_line import LineReading

    c = SensorClientCore(stale_after_feeds=100)
    f = LineReading(True, 0.5, -0.25, 0.0)
    now = 5_000_000_000_000  # ns
    ok = c.feed(format_line(f, stamp_ms_of(now - 20_000_000)), now)
    assert ok.valid and ok.age_ms == 20 and c.stamp_dropped == 0
    assert not c.feed(format_line(f, stamp_ms_of(now + 30_000_000)), now + 1_000_000).valid  # future
    assert not c.feed(format_line(f, stamp_ms_of(now - 5_000_000_000)), now + 2_000_000).valid  # 5 s old
    assert not c.feed(format_line(f, stamp_ms_of(now - 40_000_000)), now + 3_000_000).valid  # before the last
    assert c.stamp_dropped == 3
    later = c.feed(format_line(f, stamp_ms_of(now + 10_000_000)), now + 16_000_000)
    assert later.valid and later.age_ms == 6


def test_the_sensor_status_keeps_the_capture_age():
    from droid.brain.db.layouts import NO_CAPTURE_AGE, SENSOR_STATUS_LAYOUT
    from droid.brain.plumbing.sensor_line import LineReading, format_line, stamp_ms_of
    from droid.brain.runtime.sensor_link import SensorStatusCore

    assert SENSOR_STATUS_LAYOUT.version == 2 and "capture_age_us" in SENSOR_STATUS_LAYOUT.dtype.names
    core = SensorStatusCore(stale_ticks=3)
    f = LineReading(True, 0.5, -0.25, 0.0)
    t = 7_000_000_000_000
    st = core.on_tick(1, format_line(f), t)  # the first line after opening is skipped (resync)
    st = core.on_tick(2, format_line(f, stamp_ms_of(t - 12_000_000)), t + 16_000_000)
    assert st["homed"] == 0 and st["capture_age_us"] == 28_000
    st = core.on_tick(3, format_line(f), t + 32_000_000)
    assert st["capture_age_us"] == NO_CAPTURE_AGE
    st = core.on_tick(4, format_line(f, stamp_ms_of(t + 99_000_000)), t + 48_000_000)  # from the future
    assert st["homed"] == 1 and st["capture_age_us"] == NO_CAPTURE_AGE and st["garbled_count"] == 1


def test_the_sensor_core_appends_the_capture_stamp_only_when_asked():
    from droid.brain.plumbing.sensor_line import parse_line
    from droid.sim.mvs.camera import CameraNoise, lap_joint_profile_mm, quantise
    from droid.subunits.mvs.calibration import MvsCalibration
    from droid.subunits.mvs.sensor import SensorCore

    calib = MvsCalibration()
    rows = quantise(lap_joint_profile_mm(calib, 1.0, 2.0, 0.1, 2.0, 1.0), calib, CameraNoise(0.0, 0.0),
                    np.random.default_rng(1))
    core = SensorCore(calib)
    plain, stamped = parse_line(core.step(rows)), parse_line(core.step(rows, 4321))
    assert plain.valid and plain.stamp_ms is None
    assert stamped.valid and stamped.stamp_ms == 4321 and stamped.x_mm == plain.x_mm


def test_a_cells_stamp_option_turns_stamps_on_and_a_bad_one_is_refused(tmp_path):
    """``stamp = true`` in [subunits.mvs] is droid-mvs --stamp (the default cell sets it);
    a value that is not a boolean is one clear error."""
    import argparse
    import re

    import pytest

    from droid.brain.cell.cellfile import builtin_cell_path
    from droid.cli import BadInput
    from droid.subunits.mvs.sensor import apply_cell

    def args_for(text):
        path = tmp_path / "c.toml"
        path.write_text(text)
        return argparse.Namespace(cell=str(path), subunit="mvs", dsp=None, serial=None, baud=None,
                                  board_wait=None, stamp=False)

    text = builtin_cell_path().read_text()
    args = args_for(text)
    apply_cell(args)
    assert args.stamp is True
    args = args_for(re.sub(r"(?m)^stamp = true(\s+# \"x,y,roll,ms\" lines \(droid-mvs)", r"stamp = false\1", text))
    apply_cell(args)
    assert args.stamp is False
    with pytest.raises(BadInput, match="stamp must be true or false"):
        apply_cell(args_for(re.sub(r"(?m)^stamp = true(\s+# \"x,y,roll,ms\" lines \(droid-mvs)", r'stamp = "yes"\1', text)))
