"""Pure cores of the heartbeat, name space and link (no processes, no clock)."""
import pytest
from hypothesis import given, strategies as st

from droid.brain.plumbing import wire
from droid.brain.runtime.heartbeat import HeartbeatCore, TickMonitor
from droid.brain.plumbing.link import AgentLinkCore, RemoteLinkCore
from droid.brain.runtime.names import NameSpaceCore

P = 16_666_667


def test_heartbeat_counts_overruns_as_missed_ticks():
    hb = HeartbeatCore(P)
    assert hb.step(1, 100).tick == 1
    t = hb.step(3, 200)  # woke up two periods late
    assert (t.tick, t.missed) == (4, 2)


@given(st.lists(st.integers(1, 5), min_size=1, max_size=50))
def test_monitor_sees_every_missed_tick(expirations):
    hb, mon = HeartbeatCore(P), TickMonitor()
    mon.feed(hb.step(1, 0))  # the client is subscribed from the first tick
    for n in expirations:
        mon.feed(hb.step(n, 0))
    assert mon.missed == hb.missed


def test_tick_frame_round_trip_and_garbage():
    t = wire.Tick(123456789, 987654321, P, 4)
    assert wire.unpack_tick(wire.pack_tick(t)) == t
    for bad in (b"", b"x" * 40, wire.pack_tick(t)[:-1], b"DHB2" + wire.pack_tick(t)[4:]):
        with pytest.raises(wire.BadFrame):
            wire.unpack_tick(bad)


@given(st.lists(st.binary(max_size=30), max_size=6))
def test_link_unpack_rejects_garbage_cleanly(frames):
    try:
        tick, payload = wire.unpack_link(frames, wire.KIND_CMD)
    except wire.BadFrame:
        return
    assert frames[0] == wire.LINK_PROTO and len(frames) == 4


def test_remote_marks_stale_after_three_missed_ticks_and_recovers():
    core = RemoteLinkCore(stale_ticks=3)
    core.on_tick(1)
    assert core.on_reply(1) and not core.stale
    acts = [core.on_tick(t) for t in range(2, 7)]  # no replies to ticks 2, 3, 4
    # the third missed reply is known at tick 5: stale from then on
    assert [a.became_stale for a in acts] == [False, False, False, True, False]
    assert acts[3].reconnect and core.stale
    assert not core.on_reply(3)  # a late reply does not count
    assert core.on_reply(6) and not core.stale and core.missed == 0


def test_remote_reconnect_backs_off():
    core = RemoteLinkCore(stale_ticks=3, max_backoff_ticks=12)
    reconnect_ticks = [t for t in range(1, 80) if core.on_tick(t).reconnect]
    gaps = [b - a for a, b in zip(reconnect_ticks, reconnect_ticks[1:])]
    assert gaps[:3] == [6, 12, 12]


def test_agent_link_dies_after_stale_ticks():
    a = AgentLinkCore(P, 3)
    assert not a.alive(0)
    a.on_command(1, 1000)
    assert a.alive(1000 + 2 * P)
    assert not a.alive(1000 + 3 * P)


def test_name_space_register_locate_expire():
    alive = {10: True, 11: True}
    ns = NameSpaceCore("hostA", alive=lambda pid: alive.get(pid, False))
    reg = {"op": "register", "name": "arm1", "endpoint": "ipc:///tmp/a", "pid": 10, "host": "hostA", "ttl_s": 1.0}
    assert ns.handle(reg, 0)["ok"]
    assert ns.handle({"op": "locate", "name": "arm1"}, 1)["endpoint"] == "ipc:///tmp/a"
    clash = dict(reg, pid=11)
    assert not ns.handle(clash, 2)["ok"]  # a live registrant keeps its name
    remote = {"op": "register", "name": "gmf1", "endpoint": "tcp://10.0.0.2:5", "pid": 99, "host": "hostB", "ttl_s": 1.0}
    assert ns.handle(remote, 0)["ok"]  # other host: lease only
    alive[10] = False  # registrant on this host died: entry disappears at once
    assert not ns.handle({"op": "locate", "name": "arm1"}, 3)["ok"]
    assert [e["name"] for e in ns.handle({"op": "list"}, 4)["entries"]] == ["gmf1"]
    assert ns.handle({"op": "list"}, int(1.1e9))["entries"] == []  # lease expired


@pytest.mark.parametrize("req", [
    {"op": "register", "name": "", "endpoint": "ipc://x", "pid": 1, "host": "h"},
    {"op": "register", "name": "a", "endpoint": "http://x", "pid": 1, "host": "h"},
    {"op": "register", "name": "a", "endpoint": "ipc://x", "pid": "1", "host": "h"},
    {"op": "register", "name": "a", "endpoint": "ipc://x", "pid": 1, "host": "h", "ttl_s": -1},
    {"op": "locate", "name": 5},
    {"op": "frobnicate"},
])
def test_name_space_bad_requests(req):
    rep = NameSpaceCore("h").handle(req, 0)
    assert rep["ok"] is False and rep["error"]


# -- the heartbeat's own silence (issue 16: the Brain marks every subunit stale) ------
def test_heartbeat_watch_reports_a_silence_once_and_clears_on_the_next_tick():
    from droid.brain.plumbing.link import HeartbeatWatch

    period = 16_666_667
    w = HeartbeatWatch(period, stale_ticks=3)
    t = 1_000_000_000
    assert not w.on_tick(t)
    assert not w.became_silent(t + 3 * period)  # exactly stale_ticks periods: not yet
    assert w.became_silent(t + 3 * period + 1)
    assert w.silent and w.silences == 1
    assert not w.became_silent(t + 10 * period)  # reported once
    assert w.on_tick(t + 11 * period)  # the heartbeat is back
    assert not w.silent
    assert not w.became_silent(t + 12 * period)
    assert w.became_silent(t + 15 * period)
    assert w.silences == 2


def test_heartbeat_watch_counts_from_the_first_look_when_no_tick_ever_came():
    from droid.brain.plumbing.link import HeartbeatWatch

    w = HeartbeatWatch.for_rate(60.0, 3)
    assert w.poll_ms == 17
    assert not w.became_silent(5_000_000_000)
    assert w.became_silent(5_000_000_000 + 60_000_000)
