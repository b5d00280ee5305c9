"""droid-egm NAME: the PC side of an ABB arm's Externally Guided Motion link (issue 26, thesis §7.3).

The ABB subunit runs the Reis's programs where they fit and this one where the Reis has its
servo: ``droid-reis-agent`` (the generic agent: Brain link, command copy, tick relay) and
``droid-planner`` (commands -> way-points, §4.1.7) unchanged, and ``droid-egm`` in place of
``droid-servo-agent``, ``droid-servo`` and ``droid-watchdog`` -- the robot controller closes the
joint loops and keeps its own watchdog (EGM's communication timeout).  docs/abb.md.

The shell: binds the UDP address of the subunit's ``egm`` key (``udp://HOST:PORT``; its
``[interpose]`` inner address when a fault proxy serves it, ``droid-fault proxy SUB.egm``; a port in
use is one line and exit 1), answers every accepted ``EgmRobot`` at once with an ``EgmSensor`` to
its source, and on each relayed heartbeat tick -- after the planner has written that tick's
way-point, and on its own clock when the ticks stop, as the servo agent does (``TickPacer``) --
reads the controller's Command record and writes its Status record (Table 4.2) and the EGM
record ``/droid.<cell>.<sub>.egm`` (:mod:`droid.subunits.abb.egm_layout`).  The work is
:class:`droid.subunits.abb.egm_core.EgmCore`'s; :class:`EgmStation` is the cycle between them.
Datagrams dropped by the core count in the presence record's ``bad_frames``.
"""
from __future__ import annotations

import select
import socket
import sys
import time

import zmq

from droid.brain.plumbing.curve import CurveHost
from droid.brain.db.databases import open_local
from droid.brain.runtime.heartbeat import TickSubscriber
from droid.brain.runtime.program import Presence, Stop, close_all, notify_ready, presence_key, subunit_program
from droid.brain.runtime.rt import try_sched_fifo
from droid.brain.db.shmdb import Database, db_name, unlink_database
from droid.cli import BadInput, run
from droid.kinematics import load_robot
from droid.subunits.abb.config import bind_udp, egm_bind_config
from droid.subunits.abb.egm_core import MY_FAULTS, N as N_JOINTS, EgmCore, EgmOutput, reported_joint_count
from droid.subunits.abb.egm_layout import EGM_STATUS_LAYOUT
from droid.arm.pacer import TickPacer

PROG = "droid-egm"
#: datagrams read per wake-up, at most (a flood cannot starve the heartbeat cycle)
MAX_READS_PER_WAKE = 256
#: how long droid-egm waits at start for the controller's first sample before it reports ready
#: [s]: a controller already streaming (EGMStreamStart runs first in DroidEGM.mod; droid-sim's
#: twin streams from power-up) has its joint count checked against the robot file at
#: `droid-cell up`; one that starts later is checked by the core (a wrong count: malformed)
FIRST_SAMPLE_WAIT_S = 2.0


class EgmStation:
    """droid-egm's cycle, transport aside: ``take`` each datagram (returns the reply to send),
    ``cycle`` once a heartbeat period (reads the Command record, writes the Status record's
    fields and this program's fault bits under one lock, and the EGM record).  Times [ns] are
    the caller's clock: CLOCK_MONOTONIC, or virtual time in lockstep and tests."""

    def __init__(self, core: EgmCore, ctrl_command, ctrl_status, egm_db) -> None:
        self.core = core
        self.ctrl_command = ctrl_command
        self.ctrl_status = ctrl_status
        self.egm_db = egm_db
        self.last: EgmOutput | None = None

    def take(self, data: bytes, source, now_ns: int):
        """One datagram; the (bytes, address) to send back, or None."""
        return self.core.datagram(data, source, now_ns)

    def cycle(self, now_ns: int, late_ns: int = 0) -> EgmOutput:
        out = self.last = self.core.cycle(self.ctrl_command.read(), now_ns, late_ns)
        with self.ctrl_status.locked() as st:
            for k, v in out.status.items():
                st[k] = v
            st["fault"] = (int(st["fault"]) & ~MY_FAULTS) | out.fault_bits
            self.ctrl_status.mark_written()
        self.egm_db.update(**out.egm)
        return out


def answer(sock: socket.socket, station: EgmStation, data: bytes, source) -> None:
    """One datagram to the station, its reply (if any) straight back to the sender."""
    reply = station.take(data, source, time.monotonic_ns())
    if reply is not None:
        try:
            sock.sendto(*reply)
        except OSError:
            pass  # the controller went away; its next sample finds us


def first_sample(sock: socket.socket, station: EgmStation, robot: str, wait_s: float) -> None:
    """Wait up to ``wait_s`` for the controller's first ``EgmRobot``; a joint count that is not
    the robot file's is bad input (one line, exit 2: `droid-cell up` fails with it).  The
    datagrams read here go to the station as any others."""
    deadline = time.monotonic() + wait_s
    while (left := deadline - time.monotonic()) > 0:
        if not select.select([sock], [], [], left)[0]:
            return
        try:
            data, source = sock.recvfrom(65536)
        except (BlockingIOError, InterruptedError, OSError):
            continue
        n = reported_joint_count(data)
        if n is not None and n != N_JOINTS:
            raise BadInput(f"the controller at {source[0]}:{source[1]} reports {n} joints; the robot file "
                           f"{robot} has {N_JOINTS}")
        answer(sock, station, data, source)
        if n is not None:
            return


@run
def main(argv=None) -> int:
    args, cell, sub = subunit_program(
        PROG, "Drive an ABB arm through EGM: UDP feedback in, joint targets out, the controller's "
              "databases in between.", argv, arm=True)
    cfg = egm_bind_config(cell, sub)  # the [interpose] inner address when a fault proxy serves it
    model = load_robot(sub.robot)
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    ctrl_command = ctrl_status = egm_db = sock = ctx = ticks = presence = None
    egm_name = db_name(cell.name, sub.name, "egm")
    try:
        sock = bind_udp(cfg.address)
        ctrl_command = open_local(cell, sub, "ctrl_command")
        ctrl_status = open_local(cell, sub, "ctrl_status")
        egm_db = Database(egm_name, EGM_STATUS_LAYOUT, create=True)
        presence = Presence(cell.name, presence_key(PROG, sub.name), f"{PROG} {sub.name}")
        ctx = zmq.Context()
        ticks = TickSubscriber(ctx, sub.relay, CurveHost(ctx, cell, sub.host), sub.host)
        core = EgmCore(model, cell.stale_ticks, cell.heartbeat_hz)
        station = EgmStation(core, ctrl_command, ctrl_status, egm_db)
        pacer = TickPacer(cell.period_ns)
        first_sample(sock, station, sub.robot, FIRST_SAMPLE_WAIT_S)
        poller = zmq.Poller()
        poller.register(ticks.sock, zmq.POLLIN)
        poller.register(sock.fileno(), zmq.POLLIN)
        presence.ready()
        notify_ready(args.ready_fd)
        last_why = ""
        last_tick = 0
        while not Stop.requested:
            events = dict(poller.poll(int(pacer.wait_s(time.monotonic_ns()) * 1000) + 1))
            if sock.fileno() in events:
                for _ in range(MAX_READS_PER_WAKE):
                    try:
                        data, source = sock.recvfrom(65536)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:
                        continue  # an ICMP error of an earlier send
                    answer(sock, station, data, source)
            t = ticks.recv_latest() if ticks.sock in events else None
            if t is not None:
                last_tick = t.tick
                pacer.await_planner(ctrl_command, t.tick)  # the planner cycles on the same tick
            now = time.monotonic_ns()
            if t is None and not pacer.due(now):
                continue
            out = station.cycle(now, late_ns=pacer.late_ns(now))
            pacer.cycled(now, t is not None)
            if out.why != last_why:
                if out.why:
                    print(f"{PROG} {sub.name}: holding: {out.why}", file=sys.stderr, flush=True)
                last_why = out.why
            presence.beat(last_tick, pacer.cycles, pacer.untimed, pacer.late_max_ns,
                          bad_frames=core.counters.dropped + ticks.bad_frames)
    finally:
        close_all(ticks, sock, ctx.term if ctx is not None else None, ctrl_command, ctrl_status, egm_db, presence)
        if egm_db is not None:
            unlink_database(egm_name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
