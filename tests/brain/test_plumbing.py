"""One plumbing per idea (issue 17 item 2): priorities, mode numbers, the line splitter."""
from __future__ import annotations

import importlib
import inspect

import pytest

from droid.brain import layouts, rt, wire
from droid.brain.serial_line import LineSplitter
from droid.programs import PROGRAMS


def test_every_program_that_asks_for_sched_fifo_has_a_priority_in_the_table():
    for prog, module in PROGRAMS.items():
        src = inspect.getsource(importlib.import_module(module))
        if "try_sched_fifo(" not in src:
            continue
        names = {prog} | ({"droid-agent", "droid-reis-agent", "droid-gmf1-agent"} if "agent" in prog else set())
        assert names & set(rt.FIFO_PRIORITIES), prog
    assert rt.FIFO_PRIORITIES["droid-servo"] == max(rt.FIFO_PRIORITIES.values())


def test_mode_numbers_have_one_definition():
    assert [int(m) for m in layouts.CmdMode] == [0, 1, 2, 3]
    assert (layouts.JOG_MODE, layouts.HOME_MODE) == (layouts.CmdMode.JOG, layouts.CmdMode.HOME)
    assert layouts.CMD_MODE_NAMES == {0: "OFF", 1: "JOG", 2: "HOME", 3: "NORMAL"}


def test_liveness_constants_are_the_defaults():
    from droid.brain.link import AgentLinkCore, RemoteLinkCore

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
