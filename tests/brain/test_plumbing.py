"""One plumbing per idea (issue 17 item 2): priorities, mode numbers, the line splitter."""
from __future__ import annotations

import importlib
import inspect

import pytest

from droid.brain.runtime import rt
from droid.brain.db import layouts
from droid.brain.plumbing import wire
from droid.brain.plumbing.serial_line import LineSplitter
from droid.brain.cell.registry import registry
from droid.programs import PROGRAMS


def test_every_program_that_asks_for_sched_fifo_has_a_priority_in_the_table():
    for prog, module in PROGRAMS.items():
        src = inspect.getsource(importlib.import_module(module))
        if "try_sched_fifo(" not in src:
            continue
        names = {prog} | ({"droid-agent", "droid-reis-agent", "droid-gmf1-agent"} if "agent" in prog else set())
        nice = {p.name for p in registry().programs.values() if p.sched == "nice"}
        assert names & (set(rt.FIFO_PRIORITIES) | nice), prog
    assert rt.FIFO_PRIORITIES["droid-servo"] == max(rt.FIFO_PRIORITIES.values())


def test_mode_numbers_have_one_definition():
    assert [int(m) for m in layouts.CmdMode] == [0, 1, 2, 3]
    assert (layouts.JOG_MODE, layouts.HOME_MODE) == (layouts.CmdMode.JOG, layouts.CmdMode.HOME)
    assert layouts.CMD_MODE_NAMES == {0: "OFF", 1: "JOG", 2: "HOME", 3: "NORMAL"}


def test_liveness_constants_are_the_defaults():
    from droid.brain.plumbing.link import AgentLinkCore, RemoteLinkCore

    assert RemoteLinkCore().stale_ticks == wire.LIVENESS_TICKS
    assert RemoteLinkCore().max_backoff_ticks == wire.MAX_BACKOFF_TICKS
    assert AgentLinkCore(16_666_667).stale_ticks == wire.LIVENESS_TICKS


@pytest.mark.parametrize("early", [False, True])
def test_splitter_bounds_overlong_lines(early):
    s = LineSplitter(4, b"\r\n", skip_empty=True, early_overlong=early)
    out = s.feed(b"ab\r\n\r\nabcdefgh")
    assert out[0] == b"ab"
    if early:
        assert out[1:] == [b"abcde"] and s.overlong == 1
        assert s.feed(b"ij\rok\n") == [b"ok"]
    else:
        assert out[1:] == [] and s.feed(b"ij\rok\n") == [b"abcde", b"ok"] and s.overlong == 1


def test_splitter_resync_skips_to_the_next_line_end():
    s = LineSplitter(32)
    assert s.feed(b"1.0,2") == []
    s.resync()
    assert s.feed(b"00,0.1\n3.000,4.000,0.00000\n") == [b"3.000,4.000,0.00000"]
    assert s.skipped == len(b"1.0,2") + len(b"00,0.1\n")


def test_one_bind_for_server_sockets_names_the_endpoint_it_could_not_bind(tmp_path):
    import socket
    import types

    import zmq

    from droid.brain.plumbing.curve import CurveHost
    from droid.cli import RuntimeFailure

    class NoKeys(CurveHost):  # a cell without [curve]: plain sockets
        enabled = False

        def __init__(self):
            pass

    cell = types.SimpleNamespace(bind_endpoint=lambda e: e)
    ctx = zmq.Context()
    a, b = ctx.socket(zmq.ROUTER), ctx.socket(zmq.PUB)
    taken = socket.socket()
    try:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        NoKeys().bind(cell, (a, f"ipc://{tmp_path}/a"))
        busy = f"tcp://127.0.0.1:{taken.getsockname()[1]}"
        with pytest.raises(RuntimeFailure, match="cannot bind " + busy):
            NoKeys().bind(cell, (b, busy))
    finally:
        taken.close()
        a.close(0)
        b.close(0)
        ctx.term()


class _Port:
    """A pyserial-like port whose writes time out or fail on demand."""

    def __init__(self):
        self.fail = None
        self.closed = False
        self.in_waiting = 0

    def reset_input_buffer(self):
        pass

    def write(self, data):
        if self.fail is not None:
            raise self.fail
        return len(data)

    def close(self):
        self.closed = True


@pytest.mark.parametrize("keep", [False, True])
def test_port_link_write_timeout_is_an_overrun_or_a_failure(keep):
    import serial

    from droid.brain.plumbing.serial_port import PortLink

    port = _Port()
    link = PortLink(lambda: port, write_timeout_keeps_open=keep)
    assert link.open() and link.write(b"x\n")
    port.fail = serial.SerialTimeoutException("write timeout")
    assert not link.write(b"x\n")
    assert link.is_open == keep and link.write_timeouts == (1 if keep else 0)
    if keep:
        port.fail = serial.SerialException("gone")
        assert not link.write(b"x\n") and not link.is_open and port.closed and link.last_error == "gone"
