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
names of the thesis; sensors use it as ``droid-agent``.
"""
from __future__ import annotations

import sys
import time

import numpy as np
import zmq

from droid.brain import wire
from droid.brain.curve import CurveHost
from droid.brain.databases import local_layouts, open_local
from droid.brain.classes import ARM6R
from droid.brain.layouts import ARM_COMMAND_LAYOUT, FAULT_LINK, Layout, LayoutError, check_header
from droid.brain.link import AgentLinkCore
from droid.brain.names import NameClient
from droid.brain.program import Presence, Stop, notify_ready, open_cell, parser, presence_key
from droid.brain.rt import PeriodicTimer, try_sched_fifo
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
        self._runs = None if dst_layout is None else _byte_runs(layout.dtype, dst_layout.dtype, self.field_map)
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


def _byte_runs(src_dtype, dst_dtype, field_map: dict[str, str]) -> tuple | None:
    """The copy ``dst[field_map[f]] = src[f]`` as byte ranges (source offset, destination offset,
    bytes), neighbours merged -- or None unless each pair has the very same type (then a field's
    assignment is a copy of its bytes, the same bits; issue 28 item 2)."""
    runs: list[list[int]] = []
    for s, d in sorted(field_map.items(), key=lambda sd: src_dtype.fields[sd[0]][1]):
        (st, so), (dt, do) = src_dtype.fields[s][:2], dst_dtype.fields[d][:2]
        if st != dt:
            return None
        if runs and runs[-1][0] + runs[-1][2] == so and runs[-1][1] + runs[-1][2] == do:
            runs[-1][2] += st.itemsize
        else:
            runs.append([so, do, st.itemsize])
    return tuple(tuple(r) for r in runs)


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
    ap = parser(prog, "Serve a subunit to its Brain-side remote: commands in, status out, ticks relayed.")
    ap.add_argument("subunit", help="subunit name, e.g. arm1")
    args = ap.parse_args(argv)
    cell = open_cell(args)
    sub = cell.subunit(args.subunit)
    Stop.install()
    try_sched_fifo(wanted=cell.sched_fifo, prog=prog)
    layouts = local_layouts(sub)
    status = open_local(cell, sub, "ctrl_status")
    ctrl_cmd = open_local(cell, sub, "ctrl_command") if "ctrl_command" in layouts else None
    ctx = zmq.Context()
    curve = CurveHost(ctx, cell, sub.host)
    presence = Presence(cell.name, presence_key(prog, sub.name), f"{prog} {sub.name}")
    router = ctx.socket(zmq.ROUTER)
    router.setsockopt(zmq.LINGER, 0)
    router.setsockopt(zmq.MAXMSGSIZE, 65536)
    relay = ctx.socket(zmq.PUB)
    relay.setsockopt(zmq.LINGER, 0)
    names = None
    station = AgentStation(status, ctrl_cmd, cell.period_ns, cell.stale_ticks,
                           CommandCopier.for_subunit(ctrl_cmd, sub) if ctrl_cmd is not None else None)
    link = station.link
    timer = PeriodicTimer(cell.period_ns)  # checks Brain-link liveness between commands
    bad_frames = 0
    try:
        cell.run_dir.mkdir(parents=True, exist_ok=True)
        curve.bind(cell, (router, sub.agent), (relay, sub.relay))
        names = NameClient(ctx, cell.names, curve=curve, server_host=cell.brain_host)
        names.register(sub.name, sub.agent)
        presence.ready()
        notify_ready(args.ready_fd)
        poller = zmq.Poller()
        poller.register(router, zmq.POLLIN)
        poller.register(timer.fd, zmq.POLLIN)
        while not Stop.requested:
            events = dict(poller.poll(500))
            now = time.monotonic_ns()
            if router in events:
                while True:
                    try:
                        frames = router.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    if len(frames) < 2:
                        bad_frames += 1
                        continue
                    ident, body = frames[0], frames[1:]
                    try:
                        tick, payload = wire.unpack_link(body, wire.KIND_CMD)
                        reply = station.on_command(payload, tick, now)
                    except (wire.BadFrame, LayoutError):
                        bad_frames += 1
                        continue
                    router.send_multipart([ident] + wire.pack_link(wire.KIND_STA, tick, reply))
                    relay.send(wire.pack_tick(wire.Tick(tick, now, cell.period_ns)))
            if timer.fd in events:
                timer.consume()
                names.keepalive()
                local = station.on_timer(now)
                if local is not None:
                    relay.send(wire.pack_tick(wire.Tick(local, now, cell.period_ns)))
            presence.beat(link.last_tick, link.commands, timer.overruns, bad_frames=bad_frames)
    finally:
        if names is not None:
            names.close()
        router.close(0)
        relay.close(0)
        curve.close()
        ctx.term()
        timer.close()
        status.close()
        if ctrl_cmd is not None:
            ctrl_cmd.update(link_alive=0)
            ctrl_cmd.close()
        presence.close()
    return 0


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
