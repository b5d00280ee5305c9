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
from droid.brain.layouts import ARM_COMMAND_LAYOUT, FAULT_LINK, LayoutError, check_header
from droid.brain.link import AgentLinkCore
from droid.brain.names import NameClient
from droid.brain.program import Presence, Stop, notify_ready, open_cell, parser, presence_key
from droid.brain.rt import PeriodicTimer, try_sched_fifo
from droid.cli import run

# Brain Command (Table 3.2) -> controller Command (Table 4.3)
COMMAND_MAP = {
    "x": "x", "y": "y", "z": "z", "R": "R",
    "cart_time_count": "cart_time_count",
    "joint_time_count": "joint_time_count",
    "encoder_pos": "encoder_cmd_ext",
    "coord": "coord",
    "cmd_mode": "cmd_mode",
    "sent": "sent",
    "cmd_id": "cmd_id",
}


class CommandCopier:
    """Copies a Brain Command record into the controller's Command record (field map above)."""

    def __init__(self, ctrl_command) -> None:
        self.db = ctrl_command

    def __call__(self, payload: bytes, tick: int) -> None:
        check_header(payload, ARM_COMMAND_LAYOUT, "command from the Brain")
        rec = np.frombuffer(payload, dtype=ARM_COMMAND_LAYOUT.dtype, count=1)[0]
        with self.db.locked() as v:
            for src, dst in COMMAND_MAP.items():
                v[dst] = rec[src]
            v["brain_tick"] = tick
            v["link_alive"] = 1
            self.db.mark_written()


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
    copier = CommandCopier(ctrl_cmd) if ctrl_cmd is not None else None
    ctx = zmq.Context()
    curve = CurveHost(ctx, cell, sub.host)
    presence = Presence(cell.name, presence_key(prog, sub.name), f"{prog} {sub.name}")
    router = ctx.socket(zmq.ROUTER)
    router.setsockopt(zmq.LINGER, 0)
    router.setsockopt(zmq.MAXMSGSIZE, 65536)
    relay = ctx.socket(zmq.PUB)
    relay.setsockopt(zmq.LINGER, 0)
    names = None
    link = AgentLinkCore(cell.period_ns, cell.stale_ticks)
    timer = PeriodicTimer(cell.period_ns)  # checks Brain-link liveness between commands
    bad_frames = 0
    was_alive = False
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
                        if copier is not None:
                            copier(payload, tick)
                    except (wire.BadFrame, LayoutError):
                        bad_frames += 1
                        continue
                    link.on_command(tick, now)
                    if not was_alive:
                        _set_fault(status, FAULT_LINK, False)
                        was_alive = True
                    reply = status.raw_bytes()
                    router.send_multipart([ident] + wire.pack_link(wire.KIND_STA, tick, reply))
                    relay.send(wire.pack_tick(wire.Tick(tick, now, cell.period_ns)))
            if timer.fd in events:
                timer.consume()
                names.keepalive()
                if was_alive and not link.alive(now):
                    was_alive = False
                    if ctrl_cmd is not None:
                        ctrl_cmd.update(link_alive=0)
                    _set_fault(status, FAULT_LINK, True)
                if not was_alive and link.last_cmd_ns is not None:
                    # The Brain is silent: keep ticking the local programs so that the
                    # planner sees link_alive = 0 and cancels its move (the arm brakes
                    # and stays stopped).  Tick numbers follow time, like the heartbeat's.
                    local = link.last_tick + (now - link.last_cmd_ns) // cell.period_ns
                    if ctrl_cmd is not None:
                        ctrl_cmd.update(brain_tick=local)
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


PROG = "droid-agent"


@run
def main(argv=None) -> int:
    return agent_main(PROG, argv)


if __name__ == "__main__":
    sys.exit(main())
