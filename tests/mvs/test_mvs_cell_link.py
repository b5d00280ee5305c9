"""The Brain's serial link to a line-laser sensor: Status core, port reader on ptys, cell options."""
from __future__ import annotations

import math
import os
import time
import tty
from pathlib import Path

import numpy as np
import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.brain.cell.cellfile import parse_cell
from droid.brain.db.layouts import FAULT_DEVICE, FAULT_LINK
from droid.brain.runtime.sensor_link import (SensorStatusCore, SerialPortReader, link_kind, seam_status_fields,
                                     serial_link_options)
from droid.brain.plumbing.sensor_line import INVALID, LineReading
from droid.cli import BadInput

LINE = b"1.250,-3.500,0.10000\n"


def opened(stale_ticks=3):
    """A core whose port has just opened and resynchronised (a line end arrived).

    After every open the core skips up to the first line end: the port may
    have opened in the middle of a line.
    """
    core = SensorStatusCore(stale_ticks=stale_ticks)
    core.on_tick(0, b"\n", 0, True)
    return core


def tick(core, n, data=b"", ok=True):
    """Run ``n`` ticks (data on the first only); the fields of the last."""
    out = None
    for k in range(n):
        out = core.on_tick(k + 1, data if k == 0 else b"", 1000 + k, ok)
    return out


def test_first_line_after_the_port_opens_is_skipped():
    core = SensorStatusCore(stale_ticks=3)
    f = core.on_tick(1, LINE, 1, True)
    assert f["stale"] == 1 and f["valid_count"] == 0 and f["garbled_count"] == 0
    assert core.client.splitter.skipped == len(LINE)
    f = core.on_tick(2, LINE, 2, True)
    assert f["stale"] == 0 and f["valid_count"] == 1 and f["x"] == 1.25


def test_valid_line_fills_table_3_3_fields():
    core = opened()
    f = core.on_tick(7, LINE, 123_456, True)
    assert (f["x"], f["y"], f["z"]) == (1.25, -3.5, 0.0)
    c, s = math.cos(0.1), math.sin(0.1)
    assert np.allclose(f["R"], [[c, -s, 0], [s, c, 0], [0, 0, 1]])
    assert f["homed"] == 0 and f["stale"] == 0 and f["fault"] == 0
    assert (f["tick"], f["updated_ns"]) == (7, 123_456)
    assert (f["valid_count"], f["invalid_count"], f["garbled_count"]) == (1, 0, 0)


def test_invalid_and_garbled_lines_set_the_invalid_flag_and_count():
    core = opened()
    core.on_tick(1, LINE, 1, True)
    f = core.on_tick(2, b"invalid\n", 2, True)
    assert f["homed"] == 1 and (f["x"], f["y"]) == (0.0, 0.0) and np.allclose(f["R"], np.eye(3))
    assert f["stale"] == 0  # an invalid reading is fresh data, not a dead link
    f = core.on_tick(3, b"1.0,2.0,0.1\n\xff\xfe garbage\n", 3, True)
    assert f["homed"] == 1
    assert (f["valid_count"], f["invalid_count"], f["garbled_count"]) == (1, 3, 2)


def test_partial_lines_join_across_ticks_and_the_newest_wins():
    core = opened()
    f = core.on_tick(1, b"1.000,2.0", 1, True)
    assert f["stale"] == 1 and f["homed"] == 1  # nothing complete yet
    f = core.on_tick(2, b"00,0.00000\n3.000,4.000,-0.50000\n5.000,", 2, True)
    assert (f["x"], f["y"], f["homed"]) == (3.0, 4.0, 0)
    assert f["valid_count"] == 2 and f["tick"] == 2
    f = core.on_tick(3, b"6.000,0.00000\n", 3, True)
    assert (f["x"], f["y"]) == (5.0, 6.0) and f["tick"] == 3


def test_stale_after_stale_ticks_without_a_line_then_fresh_again():
    core = opened(stale_ticks=3)
    assert core.on_tick(1, LINE, 10, True)["stale"] == 0
    assert tick(core, 2)["stale"] == 0  # two silent ticks: still fresh, last reading kept
    f = core.on_tick(4, b"", 40, True)  # the third silent tick
    assert f["stale"] == 1 and f["fault"] & FAULT_LINK and f["homed"] == 1 and f["x"] == 0.0
    assert (f["tick"], f["updated_ns"]) == (1, 10)  # when the newest line came
    f = core.on_tick(5, LINE, 50, True)
    assert f["stale"] == 0 and f["fault"] == 0 and f["homed"] == 0 and f["x"] == 1.25


def test_lost_port_is_stale_with_device_fault_and_reopen_resyncs():
    core = opened(stale_ticks=3)
    core.on_tick(1, LINE, 1, True)
    f = core.on_tick(2, b"", 2, False)
    assert f["stale"] == 1 and f["fault"] == FAULT_LINK | FAULT_DEVICE and f["homed"] == 1
    # reopened in the middle of a line: its tail is skipped, not counted -- nor trusted,
    # since a tail can itself be grammatical ("11.250,..." cut to "1.250,...")
    f = core.on_tick(3, b"1.250,-3.500,0.10000\n", 3, True)
    assert f["stale"] == 1 and f["fault"] == FAULT_LINK and f["garbled_count"] == 0
    f = core.on_tick(4, LINE, 4, True)
    assert f["stale"] == 0 and f["fault"] == 0 and f["valid_count"] == 2


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.binary(max_size=60), st.booleans()), max_size=40))
def test_status_core_never_raises_and_stays_consistent(steps):
    core = SensorStatusCore(stale_ticks=2)
    for k, (data, ok) in enumerate(steps, 1):
        f = core.on_tick(k, data, k, ok)
        assert f["valid_count"] + f["invalid_count"] == core.client.lines
        assert f["garbled_count"] <= f["invalid_count"]
        if f["stale"]:
            assert f["homed"] == 1 and f["fault"] & FAULT_LINK
        if not ok:
            assert f["stale"] == 1 and f["fault"] & FAULT_DEVICE
        if f["homed"] == 0:
            assert abs(np.linalg.det(f["R"]) - 1) < 1e-9


def test_seam_status_fields_match_the_reading_transform():
    r = LineReading(True, 2.0, -1.0, -0.3)
    f = seam_status_fields(r)
    T = r.transform()
    assert np.allclose(f["R"], T[:3, :3]) and (f["x"], f["y"], f["z"]) == tuple(T[:3, 3])
    assert seam_status_fields(INVALID)["homed"] == 1


# -- the port reader, on pseudo-terminals the test controls ---------------------------

class Pty:
    """A pty whose slave is reachable at a symlink (like droid-sim's cable ends)."""

    def __init__(self, link: Path):
        self.master, slave = os.openpty()
        tty.setraw(slave)
        name = os.ttyname(slave)
        os.close(slave)
        if link.is_symlink():
            link.unlink()
        link.symlink_to(name)

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def close(self) -> None:
        if self.master >= 0:
            os.close(self.master)
            self.master = -1


@pytest.fixture
def pty_link(tmp_path):
    link = tmp_path / "sensor.tty"
    made = []

    def make():
        p = Pty(link)
        made.append(p)
        return p

    yield link, make
    for p in made:
        p.close()


def poll_until(reader, pred, limit=200):
    """Poll (one call = one tick) until pred(data, ok); returns the bytes gathered."""
    got = b""
    for _ in range(limit):
        data, ok = reader.poll()
        got += data
        if pred(got, ok):
            return got
        time.sleep(0.002)
    raise AssertionError(f"condition not met; got {got!r}")


def test_reader_reads_garbage_and_lines_without_blocking(pty_link):
    link, make = pty_link
    pty = make()
    reader = SerialPortReader(str(link), 19200)
    try:
        assert reader.poll() == (b"", True)  # open, nothing there: returns at once
        pty.write(b"\x00\xffjunk\n1.000,2.0")
        got = poll_until(reader, lambda d, ok: d.endswith(b"2.0"))
        assert got == b"\x00\xffjunk\n1.000,2.0"  # byte for byte, partial line included
    finally:
        reader.close()


def test_reader_survives_a_vanishing_port_and_reopens_with_back_off(pty_link):
    link, make = pty_link
    pty = make()
    opens = []

    def opener(url, baud):
        opens.append(url)
        return serial.serial_for_url(url, baudrate=baud, timeout=0)

    reader = SerialPortReader(str(link), 19200, min_backoff_ticks=2, max_backoff_ticks=8, opener=opener)
    try:
        assert reader.poll() == (b"", True)  # opening flushes what was waiting
        pty.write(LINE)
        assert poll_until(reader, lambda d, ok: d == LINE) == LINE
        pty.close()  # the other end goes away (droid-sim stopped)
        assert reader.poll() == (b"", False)
        assert reader.port is None and reader.failures == 1
        link.unlink()  # and its symlink with it: reopening fails, with growing waits
        results = [reader.poll()[1] for _ in range(20)]
        assert not any(results)
        # attempts after waits of 2, 4, 8, 8 ticks: far fewer than the 20 ticks
        assert 2 <= len(opens) - 1 <= 4
        assert reader.failures == len(opens)
        pty2 = make()  # the port is back (a new pty at the same path)
        poll_until(reader, lambda d, ok: ok, limit=400)
        assert reader.opens == 2
        pty2.write(LINE)
        assert poll_until(reader, lambda d, ok: d == LINE) == LINE
    finally:
        reader.close()


def test_reader_open_failure_is_not_an_error_but_a_bad_url_is(tmp_path):
    reader = SerialPortReader(str(tmp_path / "nothing.tty"), 19200)
    assert reader.poll() == (b"", False) and "nothing.tty" in reader.last_error
    with pytest.raises(BadInput, match="serial"):
        SerialPortReader("frobnicate://x", 19200).start()


# -- cell file options -----------------------------------------------------------------

def cell_with(tmp_path, mvs_table: str):
    import tomllib

    text = f"""
[cell]
name = "linkopts"
[subunits.arm1]
class = "arm6r"
robot = "reis_v15"
[subunits.mvs]
class = "line_laser"
{mvs_table}
"""
    return parse_cell(tomllib.loads(text), tmp_path / "c.toml")


def test_serial_link_options_from_the_cell(tmp_path):
    cell = cell_with(tmp_path, 'link = "serial"\nserial = "{run}/b.tty"\nbaud = 38400\ndsp = "shm://x"')
    sub = cell.subunits["mvs"]
    assert link_kind(cell, sub) == "serial"
    opts = serial_link_options(cell, sub)
    assert opts.url.endswith("/linkopts/b.tty") and opts.baud == 38400
    assert link_kind(cell, cell.subunits["arm1"]) == "agent"


@pytest.mark.parametrize("table,message", [
    ('link = "serial"', "needs serial"),
    ('link = "serial"\nserial = "/x"\nbaud = 9600', "baud = 9600: is outside [19200, 4000000] baud"),
    ('link = "serial"\nserial = "/x"\nbaud = 20000', "baud = 20000: is not one of the standard rates"),
    ('link = "serial"\nserial = "/x"\nbaud = "fast"', "baud = 'fast': must be an integer"),
    ('link = "serial"\nserial = "/x"\nbaud = nan', "baud = nan: must be an integer"),
    ('link = "serial"\nserial = "/x"\nseriall = "/y"', "unknown key(s): seriall"),
    ('link = "pigeon"', "link must be one of agent, serial"),
])
def test_bad_serial_link_options_name_the_key(tmp_path, table, message):
    with pytest.raises(BadInput) as exc:  # the cell's loader (droid.numbers) or the link's own rules
        cell = cell_with(tmp_path, table)
        sub = cell.subunits["mvs"]
        link_kind(cell, sub)
        serial_link_options(cell, sub)
    text = str(exc.value)  # the key is named as [subunits.mvs] baud or subunits.mvs.baud (droid.numbers)
    assert message in text and ("[subunits.mvs]" in text or "subunits.mvs.baud" in text), text


def test_an_arm_cannot_have_a_serial_link(tmp_path):
    import tomllib

    cell = parse_cell(tomllib.loads('[cell]\nname = "x"\n[subunits.arm1]\nclass = "arm6r"\nrobot = "reis_v15"\n'
                                    'link = "serial"\n'), tmp_path / "c.toml")
    with pytest.raises(BadInput, match="for line_laser subunits"):
        link_kind(cell, cell.subunits["arm1"])
