"""droid-gmf1-serial NAME: the GMF1 serial program (thesis §4.2.4), the shell of :class:`SerialCore`.

It subscribes to the agent's tick relay (``relay`` endpoint of the subunit);
on each relayed tick it reads the controller's Command record, runs
:class:`~droid.subunits.gmf1.serial_core.SerialCore` (newest command only,
once the previous move is DONE) and writes the Status record's busy, cmd_id,
cmd_result, ... fields.  The port is the subunit's ``serial`` key (a device
path, droid-sim's pty link, or a pyserial URL such as ``socket://host:port``)
at ``baud`` (9600), opened with ``serial.serial_for_url``; a port that is
missing or vanishes is a device fault and is reopened with back-off — the
program never exits for it.  Grammar, drop policy and faults: docs/gmf1.md.

Options: ``--serial URL`` / ``--baud N`` override the cell file.
Exit: 0 on SIGTERM/SIGINT; 2 on a bad cell file or URL; 1 if the databases are missing.
"""
from __future__ import annotations

import sys

import zmq

from droid.brain.plumbing.curve import CurveHost
from droid.brain.db.databases import open_local
from droid.brain.runtime.heartbeat import TickSubscriber
from droid.brain.runtime.program import ErrorLine, Presence, Stop, close_all, notify_ready, presence_key, subunit_program
from droid.cli import baud_rate, run
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T
from droid.guard.gate import GuardGate, guard_stale_ticks
from droid.subunits.gmf1.config import gmf1_config
from droid.subunits.gmf1.karel_wire import MIN_BAUD
from droid.brain.cell.registry import open_url
from droid.brain.runtime.rt import try_sched_fifo
from droid.subunits.gmf1.port import PortLink
from droid.subunits.gmf1.serial_core import SerialCore, SerialParams
from droid.subunits.gmf1.station import SerialStation

PROG = "droid-gmf1-serial"
POLL_MS = 500


def build_core(cell, sub, cfg, baud: int) -> SerialCore:
    model = load_robot(sub.robot).with_base(pose_to_T(*sub.base))
    params = SerialParams(period_s=1.0 / cell.heartbeat_hz, baud=baud, reply_timeout_s=cfg.reply_timeout_s,
                          done_margin_s=cfg.done_margin_s)
    return SerialCore(model, params)


@run
def main(argv=None) -> int:
    def options(ap):
        ap.add_argument("--serial", metavar="URL", default=None, help="serial port (default: the cell file's)")
        ap.add_argument("--baud", type=baud_rate(MIN_BAUD), default=None,
                        help="baud rate (default: the cell file's, 9600)")

    args, cell, sub = subunit_program(PROG, "Send the newest GMF1 command to the Fanuc KAREL server over its serial "
                                      "line.", argv, arm=True, options=options, example="gmf1")
    cfg = gmf1_config(cell, sub)
    url = args.serial or cfg.serial
    baud = args.baud or cfg.baud
    link = PortLink(open_url(url, "serial", baud=baud))  # droid.brain.plumbing.serial_port.serial_opener
    core = build_core(cell, sub, cfg, baud)
    # tick-driven like the agent and, like it, declared sched = "nice" (nice -10, not real-time;
    # docs/architecture.md): at nice 0 any normal process beside the cell took half its CPU and
    # the holder's commands reached the line up to 345 ms late
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    ctrl_command = open_local(cell, sub, "ctrl_command")
    ctrl_status = None
    ctx = None
    ticks = None
    presence = None
    try:
        ctrl_status = open_local(cell, sub, "ctrl_status")
        stale = guard_stale_ticks(cell)  # a cell that declares a collision guard: its stale rule (issue 41)
        station = SerialStation(core, link, ctrl_command, ctrl_status, None if stale is None else GuardGate(stale))
        presence = Presence(cell.name, presence_key(PROG, sub.name), f"{PROG} {sub.name}")
        ctx = zmq.Context()
        ticks = TickSubscriber(ctx, sub.relay, CurveHost(ctx, cell, sub.host), sub.host)
        ticks.say = presence.say
        link.open()  # a missing port is a fault, not a start-up failure
        presence.ready()
        notify_ready(args.ready_fd)
        errors = ErrorLine(PROG, f"serial {url}: ")
        opens = link.opens
        cycles = 0
        while not Stop.requested:
            t = ticks.wait(POLL_MS / 1000.0)
            if t is None:
                continue
            station.cycle(t.tick)
            cycles += 1
            errors.update(link.last_error)
            if link.opens != opens:
                opens = link.opens
                print(f"{PROG}: serial {url} open", file=sys.stderr)
            presence.beat(t.tick, cycles, ticks.monitor.missed, ticks.lateness_max_ns, bad_frames=ticks.bad_frames)
        print(f"{PROG}: sent {core.sent}, completed {core.completed}, dropped {core.dropped}, refused "
              f"{core.refused}, failed {core.failed}, garbled {core.garbled}, timeouts {core.timeouts}, "
              f"busy rejects {core.busy_rejects}, port opens {link.opens}", file=sys.stderr)
    finally:
        close_all(link, ticks, ctx and ctx.term, ctrl_command, ctrl_status, presence)
    return 0


if __name__ == "__main__":
    sys.exit(main())
