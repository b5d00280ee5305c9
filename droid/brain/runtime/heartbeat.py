"""droid-heartbeat: the cell's 60 Hz time base (thesis §3.2).

"The heartbeat program is a fixed timer tied to the computer's real-time clock
generating a synchronization event at a rate of 60 Hz."  Here it is a ZeroMQ
PUB socket sending one :class:`~droid.brain.plumbing.wire.Tick` per period, on absolute
deadlines (timerfd), counting missed ticks and wake-up lateness.  It registers
itself in the name space as ``heartbeat``.

Tick numbers follow time, not sends: if the process is stalled for several
periods, the ticks in between are counted as missed and the next tick sent
carries the current number, so every client sees the gap
(:class:`TickMonitor`).
"""
from __future__ import annotations

import sys
import time

import zmq

from droid.brain.plumbing import wire
from droid.brain.plumbing.curve import CurveHost
from droid.brain.db.layouts import LATENESS_NO_RECORD as NO_RECORD
from droid.brain.runtime.names import NameClient
from droid.brain.runtime.program import Presence, Stop, notify_ready, open_cell, parser, presence_key
from droid.brain.runtime.rt import PeriodicTimer, now_ns, try_sched_fifo
from droid.brain.cell.cellfile import HEARTBEAT_HZ_RANGE
from droid.cli import bounded_int, rate_hz, run

PROG = "droid-heartbeat"


class HeartbeatCore:
    """Turns timer expirations into ticks.  Pure: no clock, no I/O.

    ``step(expirations, t_ns)``: ``expirations`` periods elapsed since the last
    call (1 normally, >1 after an overrun); returns the Tick to publish.
    """

    def __init__(self, period_ns: int) -> None:
        self.period_ns = period_ns
        self.tick = 0
        self.missed = 0

    def step(self, expirations: int, t_ns: int) -> wire.Tick:
        if expirations > 1:
            self.missed += expirations - 1
        self.tick += expirations
        return wire.Tick(self.tick, t_ns, self.period_ns, self.missed)


class TickMonitor:
    """Client side: detects missed ticks from gaps in tick numbers."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.received = 0
        self.missed = 0

    def feed(self, t: wire.Tick) -> int:
        """Account for a received tick; returns how many ticks were missed before it."""
        gap = 0
        if self.last is not None and t.tick > self.last + 1:
            gap = t.tick - self.last - 1
            self.missed += gap
        self.last = t.tick if self.last is None else max(self.last, t.tick)
        self.received += 1
        return gap


class TickSubscriber:
    """SUB socket on a heartbeat (or an agent's relay) endpoint.

    ``curve``/``server_host``: the CURVE keys of this program's host and the
    host that publishes (used for ``tcp://`` endpoints of a cell with keys).

    ``lateness_max_ns``: the worst delay from a tick's stamp (``t_ns``, the publisher's
    CLOCK_MONOTONIC when it sent it) to this program reading it [ns] -- the tick follower's
    own lateness record, as :class:`droid.brain.runtime.rt.PeriodicTimer` keeps one for a timed loop.
    Kept only where publisher and reader share one clock, an ``ipc://`` endpoint (one
    machine), from the first read on (what queued before it waited for the program's start-up,
    not its loop); elsewhere it stays ``NO_RECORD``.  ``late_ticks`` counts the ticks read
    ``LATE_SAY_NS`` late or more; ``say`` (a program's log line writer, optional) hears of
    each new worst of them and of the rest at most every ``SAY_EVERY_NS``, with the
    CLOCK_MONOTONIC time, so that a stall can be matched with other programs' logs."""

    LATE_SAY_NS = 20_000_000  # issue 40: "late by 20 ms or more"
    SAY_EVERY_NS = 10_000_000_000

    def __init__(self, ctx: zmq.Context, endpoint: str, curve: CurveHost | None = None,
                 server_host: str = "") -> None:
        self.sock = ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.SUBSCRIBE, b"")
        self.sock.setsockopt(zmq.RCVHWM, 4)
        self.sock.setsockopt(zmq.LINGER, 0)
        if curve is not None:
            curve.client(self.sock, endpoint, server_host)
        self.sock.connect(endpoint)
        self.monitor = TickMonitor()
        self.bad_frames = 0
        self.same_clock = endpoint.startswith("ipc://")
        self.lateness_max_ns = 0 if self.same_clock else NO_RECORD
        self.late_ticks = 0
        self.say = None
        self._said_ns = 0
        self._armed_ns = None  # the first read: ticks stamped before it waited for start-up, not the loop

    def recv_latest(self) -> wire.Tick | None:
        """Drain the socket; returns the newest valid tick (None if nothing valid)."""
        newest = None
        if self._armed_ns is None:
            self._armed_ns = time.monotonic_ns()
        while True:
            try:
                frame = self.sock.recv(zmq.NOBLOCK)
            except zmq.Again:
                return newest
            try:
                t = wire.unpack_tick(frame)
            except wire.BadFrame:
                self.bad_frames += 1
                continue
            self.monitor.feed(t)
            if newest is None or t.tick > newest.tick:
                newest = t
            if self.same_clock and t.t_ns >= self._armed_ns:
                self._lateness(t, time.monotonic_ns())

    def _lateness(self, t: wire.Tick, now: int) -> None:
        late = now - t.t_ns
        worst = late > self.lateness_max_ns
        if worst:
            self.lateness_max_ns = late
        if late < self.LATE_SAY_NS:
            return
        self.late_ticks += 1
        if self.say is not None and (worst or now - self._said_ns >= self.SAY_EVERY_NS):
            self._said_ns = now
            self.say(f"read heartbeat tick {t.tick} {late / 1e6:.1f} ms after it was sent (at {now / 1e9:.3f} s "
                     f"CLOCK_MONOTONIC; {self.late_ticks} tick(s) {self.LATE_SAY_NS // 1_000_000} ms late or more so far)")

    def wait(self, timeout_s: float) -> wire.Tick | None:
        """Block up to ``timeout_s`` for the next tick."""
        if self.sock.poll(int(timeout_s * 1000)):
            return self.recv_latest()
        return None

    def close(self) -> None:
        self.sock.close(0)


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Publish the cell's heartbeat tick (default 60 Hz) on absolute deadlines.")
    ap.add_argument("--rate", type=rate_hz(*HEARTBEAT_HZ_RANGE), default=None, metavar="HZ",
                    help="tick rate [Hz] (default: the cell file's heartbeat_hz)")
    ap.add_argument("--count", type=bounded_int(0, 2**62, "ticks"), default=0, metavar="N",
                    help="stop after N ticks (default: run until SIGTERM/SIGINT)")
    args = ap.parse_args(argv)
    cell = open_cell(args)
    rate = args.rate or cell.heartbeat_hz
    period_ns = int(round(1e9 / rate))
    Stop.install()
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    ctx = zmq.Context()
    curve = CurveHost(ctx, cell, cell.brain_host)
    pub = ctx.socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    presence = Presence(cell.name, presence_key(PROG), PROG)
    names = None
    failed = False
    try:
        cell.run_dir.mkdir(parents=True, exist_ok=True)
        curve.server(pub, cell.heartbeat)
        pub.bind(cell.bind_endpoint(cell.heartbeat))
        names = NameClient(ctx, cell.names, curve=curve, server_host=cell.brain_host)
        names.register("heartbeat", cell.heartbeat)
        core = HeartbeatCore(period_ns)
        timer = PeriodicTimer(period_ns)
        presence.ready()
        notify_ready(args.ready_fd)
        poller = zmq.Poller()
        poller.register(timer.fd, zmq.POLLIN)
        while not Stop.requested:
            if not poller.poll(1000):
                continue
            n = timer.consume()
            if not n:
                continue
            t = core.step(n, now_ns())
            pub.send(wire.pack_tick(t))
            presence.beat(t.tick, timer.cycles, timer.overruns, timer.lateness_max_ns)
            names.keepalive()
            if args.count and t.tick >= args.count:
                break
        timer.close()
        print(f"{PROG}: {core.tick} ticks, {core.missed} missed, worst lateness "
              f"{timer.lateness_max_ns / 1e3:.0f} us", file=sys.stderr)
    except zmq.ZMQError as exc:
        failed = True
        raise_runtime(f"cannot bind heartbeat endpoint {cell.heartbeat}: {exc}")
    finally:
        if names is not None:
            names.close()
        pub.close(0)
        curve.close()
        ctx.term()
        presence.close(failed=failed)
    return 0


def raise_runtime(msg: str):
    from droid.cli import RuntimeFailure

    raise RuntimeFailure(msg)


if __name__ == "__main__":
    sys.exit(main())
