"""droid-guard (``droid-guard run``): the collision guard on a live cell (issue 41; docs/guard.md).

A Brain program: ``droid-cell up`` starts it on the Brain's host where the cell declares a
``[guard]`` table.  On every heartbeat tick (the heartbeat's PUB endpoint, as droid-remote) the
:class:`~droid.guard.station.GuardStation` reads every arm's Brain Status (``encoder_pos``,
``encoder_cmd``), runs one pass and

* sets FAULT_COLLISION in every arm's own Status (``ctrl_status``, as droid-ft writes
  FAULT_FORCE) on a protective stop;
* writes ``guard_tick`` and ``guard_override`` into every arm's Brain Command (the planners'
  stale rule and override: droid.guard.gate);
* writes its own Status, ``/droid.<cell>.guard.status`` (layout ``guard_status``:
  droid-snoop guard, droid-record).

On exit (SIGINT, SIGTERM, ``--seconds``) it clears the FAULT_COLLISION bits it set; the planners
then see its record go stale and stop (FAULT_GUARD) -- a dead guard stops the cell.
"""
from __future__ import annotations

import sys
import time

import zmq

from droid.brain.cell.cellfile import load_cell
from droid.brain.plumbing.curve import CurveHost
from droid.brain.db.databases import open_brain, open_local
from droid.brain.runtime.heartbeat import TickSubscriber
from droid.brain.db.layouts import GUARD_STATUS_LAYOUT
from droid.brain.runtime.program import Presence, Stop, close_all, notify_ready, presence_key, use_cell
from droid.brain.runtime.rt import try_sched_fifo
from droid.brain.db.shmdb import Database, NoDatabase, db_name
from droid.cli import BadInput
from droid.guard.gate import DEFAULT_STALE_TICKS, guard_stale_ticks
from droid.guard.station import GuardStation, guard_core
from droid.kinematics import load_robot

PROG = "droid-guard"


def status_name(cell) -> str:
    """The guard's Status record: ``/droid.<cell>.guard.status``."""
    return db_name(cell.name, "guard", "status")


def open_status(cell, create_missing: bool = False) -> Database:
    """The guard's Status record (``droid-cell up`` makes it where the cell declares a guard)."""
    try:
        return Database(status_name(cell), GUARD_STATUS_LAYOUT)
    except NoDatabase:
        if not create_missing:
            raise
        return Database(status_name(cell), GUARD_STATUS_LAYOUT, create=True)


def run_live(cell_path, seconds: float | None, ready_fd: int | None = None) -> int:
    """The live loop (see the module docstring); 0 on a clean stop."""
    if seconds is not None and not seconds > 0:
        raise BadInput("run: --seconds must be > 0")
    cell = load_cell(cell_path)
    use_cell(cell)
    if "guard" not in cell.raw:
        raise BadInput(f"{cell.path}: no [guard] table: this cell declares no collision guard (docs/guard.md)")
    core = guard_core(cell)
    stale = guard_stale_ticks(cell) or DEFAULT_STALE_TICKS
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    arms, dbs = {}, []
    ctx = zmq.Context()
    presence = ticks = curve = None
    try:
        for name in core.scene.arms:
            sub = cell.subunit(name)
            brain, local = open_brain(cell, sub, "status"), open_local(cell, sub, "ctrl_status")
            command = open_brain(cell, sub, "command")
            dbs += [brain, local, command]
            arms[name] = (load_robot(sub.robot).gearing, brain, local, command)
        status_db = open_status(cell, create_missing=True)
        dbs.append(status_db)
        # a planner's arm reports its next way-point in encoder_cmd; another arm (a controller
        # that interpolates its own moves) its move's target: see GuardStation.joints
        waypoints = {n for n in core.scene.arms if "droid-planner" in cell.subunit(n).programs}
        station = GuardStation(core, arms, status_db, stale, waypoints)
        Stop.install()
        curve = CurveHost(ctx, cell, cell.brain_host)
        ticks = TickSubscriber(ctx, cell.heartbeat, curve, cell.brain_host)
        presence = Presence(cell.name, presence_key(PROG), PROG)
        ticks.say = presence.say
        presence.ready()
        notify_ready(ready_fd)
        end = None if seconds is None else time.monotonic() + seconds
        last_state, last = None, 0
        try:
            while not Stop.requested and (end is None or time.monotonic() < end):
                t = ticks.wait(0.5)
                if t is not None:
                    last = t.tick
                    station.on_tick(t.tick)
                    for note in station.last.notes if station.last is not None else ():  # each said once
                        print(f"{PROG}: {note}", file=sys.stderr, flush=True)
                    st = station.status
                    if st["state"] != last_state:
                        print(f"{PROG}: {st['state']}: {st['distance_mm']:.1f} mm ({' with '.join(st['pair'])}); "
                              f"deciding {st.get('deciding_mm', st['distance_mm']):.1f} mm "
                              f"({' with '.join(st.get('deciding_pair', st['pair']))}) closing "
                              f"{st.get('closing_mm_s', 0.0):.0f} mm/s, S_p {st.get('separation_mm', 0.0):.1f} mm",
                              file=sys.stderr, flush=True)
                        last_state = st["state"]
                presence.beat(last, station.cycles, ticks.monitor.missed, ticks.lateness_max_ns,
                              bad_frames=ticks.bad_frames)
        finally:
            if station.faulted:
                station.release()
    finally:
        close_all(ticks, curve, ctx.term, *dbs, presence)
    return 0
