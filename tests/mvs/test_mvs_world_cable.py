"""The simulated serial line: pacing at the baud rate, byte exactness, pty ends and symlinks."""
from __future__ import annotations

import fcntl
import os
import struct
import termios
import time

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.cli import BadInput
from droid.sim.serial_cable import BytePacer, PacedPipe, PtyEnd, SerialCable, serial_cable

BAUD = 19200
BYTES_PER_S = BAUD / 10
DT = 0.005  # the default world's step (200 Hz)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.binary(max_size=50), st.floats(0.0, 0.05)), max_size=60),
       st.sampled_from([9600, 19200, 115200]))
def test_pacer_is_byte_exact_and_never_beats_the_baud_rate(steps, baud):
    pacer = BytePacer(baud, capacity_bytes=64)
    taken, out, t = b"", [], 0.0
    for data, dt in steps:
        n = pacer.push(data)
        taken += data[:n]
        out.append((t, t + dt, pacer.advance(dt)))
        t += dt
    sent = b"".join(chunk for _, _, chunk in out)
    assert taken.startswith(sent) and len(taken) - len(sent) == pacer.queued
    # over any run of consecutive steps: bytes <= span * baud/10 + 1
    for i in range(len(out)):
        total = 0
        for j in range(i, len(out)):
            total += len(out[j][2])
            assert total <= (out[j][1] - out[i][0]) * baud / 10 + 1 + 1e-9


def test_pacer_runs_at_the_baud_rate_when_fed():
    pacer = BytePacer(BAUD, capacity_bytes=64)
    sent = 0
    for _ in range(200):  # one second of 5 ms steps, the queue kept full
        pacer.push(b"x" * pacer.room)
        sent += len(pacer.advance(DT))
    assert BYTES_PER_S - 2 <= sent <= BYTES_PER_S + 1


def test_paced_pipe_delivers_lines_a_transmission_time_later_and_drops_whole_writes():
    pipe = PacedPipe(BAUD, capacity_bytes=64)
    line = b"1.000,2.000,0.10000\n"  # 20 bytes: 10.4 ms at 19200 baud
    assert pipe.write(line, 0)
    assert pipe.read(5_000_000) == line[:9]  # 9.6 bytes by 5 ms
    assert pipe.read(11_000_000) == line[9:]
    for k in range(3):
        assert pipe.write(line, 20_000_000)
    assert not pipe.write(line, 20_000_000) and pipe.dropped_writes == 1  # 80 > 64 bytes
    assert pipe.read(20_000_000 + int(60 / BYTES_PER_S * 1e9) + 1_000_000) == line * 3


def fionread(fd: int) -> int:
    return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]


def wait_until(pred, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError("timed out")
        time.sleep(0.005)


@pytest.fixture
def cable(tmp_path):
    c = SerialCable("cable", str(tmp_path / "a.tty"), str(tmp_path / "b.tty"), BAUD)
    ports = []

    def open_end(name):
        p = serial.serial_for_url(str(tmp_path / name), baudrate=BAUD, timeout=0)
        ports.append(p)
        return p

    yield c, open_end
    for p in ports:
        p.close()
    c.close()


def test_cable_carries_bytes_exactly_at_the_baud_rate(cable):
    c, open_end = cable
    a, b = open_end("a.tty"), open_end("b.tty")
    payload = bytes(range(256)) * 12  # 3072 bytes, every value: no CR/LF translation, no echo
    a.write(payload)
    wait_until(lambda: fionread(c.a.master) == len(payload))  # all of it queued at end A
    for _ in range(200):  # one virtual second
        c.advance(DT)
    sent = c.carried[0]
    assert BYTES_PER_S - 64 <= sent <= BYTES_PER_S + 1
    received = b""
    deadline = time.monotonic() + 5
    while len(received) < sent and time.monotonic() < deadline:
        received += b.read(b.in_waiting or 1)
    assert received == payload[:sent]
    while c.carried[0] < len(payload):
        c.advance(DT)
    wait_until(lambda: b.in_waiting >= len(payload) - sent)
    received += b.read(b.in_waiting)
    assert received == payload and c.lost_bytes == 0
    assert a.in_waiting == 0  # simplex: nothing came back, no echo


def test_simplex_cable_discards_what_the_receiver_sends(cable):
    c, open_end = cable
    a, b = open_end("a.tty"), open_end("b.tty")
    b.write(b"back-talk\n")
    wait_until(lambda: fionread(c.b.master) == 10)
    for _ in range(20):
        c.advance(DT)
    assert fionread(c.b.master) == 0 and a.in_waiting == 0


def test_duplex_cable_carries_both_ways(tmp_path):
    c = SerialCable("d", str(tmp_path / "a"), str(tmp_path / "b"), BAUD, duplex=True)
    a = serial.serial_for_url(str(tmp_path / "a"), baudrate=BAUD, timeout=0)
    b = serial.serial_for_url(str(tmp_path / "b"), baudrate=BAUD, timeout=0)
    try:
        a.write(b"ping\n")
        b.write(b"pong\n")
        wait_until(lambda: fionread(c.a.master) == 5 and fionread(c.b.master) == 5)
        for _ in range(10):
            c.advance(DT)
        wait_until(lambda: a.in_waiting == 5 and b.in_waiting == 5)
        assert b.read(5) == b"ping\n" and a.read(5) == b"pong\n"
    finally:
        a.close()
        b.close()
        c.close()


def test_pty_end_replaces_a_stale_symlink_refuses_a_file_and_cleans_up(tmp_path):
    path = tmp_path / "sub" / "x.tty"
    path.parent.mkdir()
    path.symlink_to("/dev/pts/nonexistent")  # left by a world that was killed
    end = PtyEnd(str(path))
    assert os.readlink(path) == end.tty_name and os.path.exists(end.tty_name)
    end.close()
    assert not os.path.lexists(path)
    end.close()  # twice is harmless
    path.write_text("not a tty")
    with pytest.raises(BadInput, match="not a symlink"):
        PtyEnd(str(path))
    assert path.read_text() == "not a tty"


def test_pty_end_outlives_its_user_closing_and_reopening(tmp_path):
    end = PtyEnd(str(tmp_path / "e.tty"))
    try:
        for _ in range(2):
            p = serial.serial_for_url(str(tmp_path / "e.tty"), baudrate=BAUD, timeout=0)
            p.write(b"hello\n")
            p.close()
            wait_until(lambda: fionread(end.master) >= 6)
            assert end.read() == b"hello\n"
        assert end.read() == b""  # nothing there: no error, no blocking
    finally:
        end.close()


class _World:
    cell = None
    devices: dict = {}


@pytest.mark.parametrize("options,message", [
    ({"ends": ["a"]}, "ends must be two paths"),
    ({"ends": ["a", 3]}, "ends must be two paths"),
    ({"ends": ["x", "x"]}, "different paths"),
    ({"ends": ["a", "b"], "baud": 0}, "baud: must be > 0"),
    ({"ends": ["a", "b"], "baud": 19200.5}, "baud must be int"),
    ({"ends": ["a", "b"], "parity": "E"}, "unknown key(s): parity"),
    ({}, "is missing 'ends'"),
])
def test_cable_options_are_checked(tmp_path, options, message):
    opts = {k: ([str(tmp_path / e) if isinstance(e, str) else e for e in v] if k == "ends" else v)
            for k, v in options.items()}
    with pytest.raises(BadInput) as exc:
        serial_cable(_World(), "mvs_cable", opts)
    assert message in str(exc.value) and "[world.devices.mvs_cable]" in str(exc.value)
    assert not any(p.is_symlink() for p in tmp_path.iterdir())
