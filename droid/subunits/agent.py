"""droid-agent NAME: a subunit's server for its Brain-side remote (thesis §3.2, §4.1.8, §4.2.3).

"Once the package is received by the Reis Agent program, the command data is
copied into the command shared memory area of the Reis motion controller.
Status data from the motion controller is also copied and packed into a Native
Message Passing packet ... sent back to the Remote Reis program to form a
reply.  In addition, a heartbeat relay message is sent to the Planner program."

The agent binds a ROUTER socket at the subunit's ``agent`` endpoint and
registers the subunit's name in the name space; it relays every tick it
receives on a PUB socket at the subunit's ``relay`` endpoint, where the
subunit's own tick-driven programs (planner, serial program) subscribe.

If the Brain stays silent for ``stale_ticks`` periods the agent sets
``link_alive = 0`` in the local Command record and the LINK fault in the local
Status record, and from then on relays ticks of its own clock, so the
subunit's tick-driven programs see it: the motion controller brakes and waits
for a new command.

``droid-reis-agent`` and ``droid-gmf1-agent`` are this program under the
names of the thesis; sensors use it as ``droid-agent``.  Named several subunits
of one host (``droid-agent joy xjoy0 ...``; a cell's ``[cell] share``, issue 28
item 4) one process serves them all: each keeps its ROUTER, relay, name,
records and link rule, in one loop -- a subunit costs its sockets, not a
process's wake-ups.
"""
from __future__ import annotations

import sys
import time

import numpy as np
import zmq

from droid.brain.plumbing import wire
from droid.brain.plumbing.curve import CurveHost
from droid.brain.db.databases import local_layouts, open_local
from droid.brain.cell.classes import ARM6R
from droid.brain.db.layouts import ARM_COMMAND_LAYOUT, FAULT_LINK, Layout, LayoutError, byte_runs, check_header
from droid.brain.plumbing.link import AgentLinkCore
from droid.brain.runtime.names import NameClient
from droid.brain.runtime.program import Presence, Stop, close_all, notify_ready, serving_presence, subunit_program
from droid.brain.runtime.rt import PeriodicTimer, try_sched_fifo
from droid.cli import run

# Brain Command (Table 3.2) -> controller Command (Table 4.3): the arm class's map
COMMAND_MAP = ARM6R.command_map


class CommandCopier:
    """Copies a Brain Command record into the subunit's local Command record: the fields of
    its class's ``command_map`` (Brain field -> local field), then the relayed tick and
    ``link_alive = 1``.  A record of another layout is refused (LayoutError), nothing copied."""

    def __init__(self, ctrl_command, layout: Layout = ARM_COMMAND_LAYOUT,
                 field_map: dict[str, str] | None = None) -> None:
        self.db = ctrl_command
        self.layout = layout
        self.field_map = dict(COMMAND_MAP if field_map is None else field_map)
        dst_layout = getattr(ctrl_command, "layout", None)
        self._runs = None if dst_layout is None else byte_runs(layout.dtype, dst_layout.dtype, self.field_map)
        self._dst: tuple | None = None  # (the record view, its bytes as a writable memoryview)

    @classmethod
    def for_subunit(cls, ctrl_command, sub) -> "CommandCopier":
        return cls(ctrl_command, sub.kind.brain["command"], sub.kind.command_map)

    def __call__(self, payload: bytes, tick: int) -> None:
        check_header(payload, self.layout, "command from the Brain")
        with self.db.locked() as v:
            if self._runs is not None:  # every field the same type on both sides: its bytes
                if self._dst is None or self._dst[0] is not v:
                    self._dst = (v, memoryview(v.reshape(1).view(np.uint8)))
                raw, src = self._dst[1], memoryview(payload)
                for s0, d0, n in self._runs:
                    raw[d0:d0 + n] = src[s0:s0 + n]
            else:
                rec = np.frombuffer(payload, dtype=self.layout.dtype, count=1)[0]
                for src, dst in self.field_map.items():
                    v[dst] = rec[src]
            v["brain_tick"] = tick
            v["link_alive"] = 1
            self.db.mark_written()


class AgentStation:
    """The agent's cycle, transport aside: a command from the remote is copied into the
    controller's Command record (if the subunit has one) and answered with the Status
    record's bytes; between commands :meth:`on_timer` watches the Brain link (§3.2).

    When the Brain has been silent for ``stale_ticks`` periods the link is declared dead:
    ``link_alive = 0`` in the Command record, FAULT_LINK in the Status record, and from
    then on the agent ticks the subunit's programs from its own clock (tick numbers follow
    time, like the heartbeat's) so that the planner cancels the interrupted move.  The next
    command clears FAULT_LINK.  Times [ns] are the caller's clock (monotonic or virtual).
    """

    def __init__(self, status, ctrl_command, period_ns: int, stale_ticks: int,
                 copier: CommandCopier | None = None) -> None:
        self.status = status
        self.ctrl_command = ctrl_command
        # an arm's copier unless the caller gives its class's (CommandCopier.for_subunit)
        self.copier = copier or (CommandCopier(ctrl_command) if ctrl_command is not None else None)
        self.link = AgentLinkCore(period_ns, stale_ticks)
        self.period_ns = period_ns
        self.alive = False  # the Brain link as last declared

    def on_command(self, payload: bytes, tick: int, now_ns: int) -> bytes:
        """A command for ``tick`` (the Brain's Command record); returns the reply (the Status
        record).  Raises LayoutError for a record of a foreign layout (nothing is copied)."""
        if self.copier is not None:
            self.copier(payload, tick)
        self.link.on_command(tick, now_ns)
        if not self.alive:
            _set_fault(self.status, FAULT_LINK, False)
            self.alive = True
        return self.status.raw_bytes()

    def on_timer(self, now_ns: int) -> int | None:
        """Once a heartbeat period: declare a silent link dead; while it is, return the local
        tick to relay to the subunit's programs (None while the Brain is heard)."""
        if self.alive and not self.link.alive(now_ns):
            self.alive = False
            if self.ctrl_command is not None:
                self.ctrl_command.update(link_alive=0)
            _set_fault(self.status, FAULT_LINK, True)
        if self.alive or self.link.last_cmd_ns is None:
            return None
        local = self.link.last_tick + (now_ns - self.link.last_cmd_ns) // self.period_ns
        if self.ctrl_command is not None:
            self.ctrl_command.update(brain_tick=local)
        return local


def agent_main(prog: str, argv=None) -> int:
    """The agent of one subunit -- or, named several (``[cell] share``, issue 28 item 4), of each
    of them from one process: each subunit keeps its own ROUTER, relay, name, station and
    records; one loop, one liveness timer and one name-service client serve them all."""
    args, cell, subs = subunit_program(
        prog, "Serve subunits to their Brain-side remotes: commands in, status out, ticks relayed.", argv,
        example="arm1 (several: one process serves them all)", several=True, one_host=True)
    try_sched_fifo(wanted=cell.sched_fifo, prog=prog)
    ctx = zmq.Context()
    curve = CurveHost(ctx, cell, subs[0].host)
    presence = serving_presence(cell, prog, subs)
    timer = PeriodicTimer(cell.period_ns)  # checks Brain-link liveness between commands
    names = None
    served: list[_AgentServed] = []
    try:
        cell.run_dir.mkdir(parents=True, exist_ok=True)
        for sub in subs:
            served.append(_AgentServed(ctx, cell, sub, curve))
        names = NameClient(ctx, cell.names, curve=curve, server_host=cell.brain_host)
        for a in served:
            names.register(a.sub.name, a.sub.agent)
        presence.ready()
        notify_ready(args.ready_fd)
        _serve(served, timer, names, presence, cell.period_ns)
    finally:
        close_all(names, *served, curve, ctx.term, timer, presence)
    return 0


class _AgentServed:
    """One subunit a droid-agent serves: its local records, station, ROUTER and relay."""

    def __init__(self, ctx, cell, sub, curve: CurveHost) -> None:
        self.sub = sub
        self.period_ns = cell.period_ns
        self.status = self.ctrl_cmd = self.router = self.relay = None
        try:
            self.status = open_local(cell, sub, "ctrl_status")
            if "ctrl_command" in local_layouts(sub):
                self.ctrl_cmd = open_local(cell, sub, "ctrl_command")
            self.station = AgentStation(self.status, self.ctrl_cmd, cell.period_ns, cell.stale_ticks,
                                        CommandCopier.for_subunit(self.ctrl_cmd, sub)
                                        if self.ctrl_cmd is not None else None)
            self.router = ctx.socket(zmq.ROUTER)
            self.router.setsockopt(zmq.LINGER, 0)
            self.router.setsockopt(zmq.MAXMSGSIZE, 65536)
            self.relay = ctx.socket(zmq.PUB)
            self.relay.setsockopt(zmq.LINGER, 0)
            curve.bind(cell, (self.router, sub.agent), (self.relay, sub.relay))
        except BaseException:
            self.close()
            raise
        self.bad_frames = 0

    def drain(self, now: int) -> None:
        """Every command waiting on the ROUTER: copied in, answered, the tick relayed."""
        router, station = self.router, self.station
        while True:
            try:
                frames = router.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                break
            if len(frames) < 2:
                self.bad_frames += 1
                continue
            ident, body = frames[0], frames[1:]
            try:
                tick, payload = wire.unpack_link(body, wire.KIND_CMD)
                reply = station.on_command(payload, tick, now)
            except (wire.BadFrame, LayoutError):
                self.bad_frames += 1
                continue
            router.send_multipart([ident] + wire.pack_link(wire.KIND_STA, tick, reply))
            self.relay.send(wire.pack_tick(wire.Tick(tick, now, self.period_ns)))

    def on_timer(self, now: int) -> None:
        local = self.station.on_timer(now)
        if local is not None:
            self.relay.send(wire.pack_tick(wire.Tick(local, now, self.period_ns)))

    def close(self) -> None:
        for sock in (self.router, self.relay):
            if sock is not None:
                sock.close(0)
        if self.ctrl_cmd is not None:
            try:
                self.ctrl_cmd.update(link_alive=0)
            finally:
                self.ctrl_cmd.close()
        if self.status is not None:
            self.status.close()


def _serve(served: list[_AgentServed], timer: PeriodicTimer, names: NameClient, presence: Presence,
           period_ns: int) -> None:
    """droid-agent's loop, until SIGTERM: commands from the remotes on every ROUTER; once a
    period, the name-service keepalive and each subunit's link-liveness rule."""
    poller = zmq.Poller()
    by_socket = {}
    for a in served:
        poller.register(a.router, zmq.POLLIN)
        by_socket[a.router] = a
    poller.register(timer.fd, zmq.POLLIN)
    links = [a.station.link for a in served]
    while not Stop.requested:
        events = dict(poller.poll(500))
        now = time.monotonic_ns()
        for sock in events:
            a = by_socket.get(sock)
            if a is not None:
                a.drain(now)
        if timer.fd in events:
            timer.consume()
            names.keepalive()
            for a in served:
                a.on_timer(now)
        if presence.due():
            presence.beat(max(link.last_tick for link in links), sum(link.commands for link in links),
                          timer.overruns, bad_frames=sum(a.bad_frames for a in served))


def _set_fault(db, bit: int, on: bool) -> None:
    with db.locked() as v:
        f = int(v["fault"])
        v["fault"] = (f | bit) if on else (f & ~bit)
        db.mark_written()


def agent_program(prog: str, module: str):
    """The ``main`` of an agent program: :func:`agent_main` under the name ``prog``, its one-line
    errors (:func:`droid.cli.run`) named by ``module``'s PROG as every program's are."""
    def main(argv=None) -> int:
        return agent_main(prog, argv)

    main.__module__ = module
    return run(main)


PROG = "droid-agent"
main = agent_program(PROG, __name__)


if __name__ == "__main__":
    sys.exit(main())
