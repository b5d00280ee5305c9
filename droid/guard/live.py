"""``droid-guard run``: the collision guard on a live cell (issue 41; docs/guard.md).

Every heartbeat period (``PeriodicTimer``): the :class:`~droid.guard.station.GuardStation`
over every arm's Brain Status (``encoder_pos``, ``encoder_cmd``) and its own Status
(``ctrl_status``, where FAULT_COLLISION goes, as droid-ft writes FAULT_FORCE); its own Status
as JSON in ``{run}/guard_status.json`` on every change of state and once a second.  On exit
(SIGINT, SIGTERM, ``--seconds``) it clears the bits it set.

Not yet: a Status database of its own, the planners' stale rule on it ("a dead guard stops the
cell"), a place in ``droid-cell up``; tests/guard/test_guard_live.py (integration) ran once
(docs/guard.md, "Not done").
"""
from __future__ import annotations

import json
import sys
import time

from droid.brain.cellfile import load_cell
from droid.brain.databases import open_brain, open_local
from droid.brain.program import Stop, use_cell
from droid.brain.rt import PeriodicTimer
from droid.cli import BadInput
from droid.guard.station import GuardStation, guard_core
from droid.kinematics import load_robot

STATUS_FILE = "guard_status.json"
STATUS_EVERY_S = 1.0


def _write_status(cell, station: GuardStation) -> None:
    st = dict(station.status)
    st["pair"] = list(st.get("pair", ("", "")))
    path = cell.run_dir / STATUS_FILE
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(st, default=float) + "\n")
    tmp.replace(path)


def run_live(cell_path, seconds: float | None) -> int:
    """The live loop (see the module docstring); 0 on a clean stop."""
    if seconds is not None and not seconds > 0:
        raise BadInput("run: --seconds must be > 0")
    cell = load_cell(cell_path)
    use_cell(cell)
    core = guard_core(cell)
    arms, dbs = {}, []
    for name in core.scene.arms:
        sub = cell.subunit(name)
        brain, local = open_brain(cell, sub, "status"), open_local(cell, sub, "ctrl_status")
        dbs += [brain, local]
        arms[name] = (load_robot(sub.robot).gearing, brain, local)
    station = GuardStation(core, arms)
    Stop.install()
    timer = PeriodicTimer(cell.period_ns)
    end = None if seconds is None else time.monotonic() + seconds
    last_state, last_write, tick = None, 0.0, 0
    try:
        while not Stop.requested and (end is None or time.monotonic() < end):
            if not timer.wait(0.5):
                continue
            tick += 1
            station.on_tick(tick)
            now = time.monotonic()
            if station.status["state"] != last_state or now - last_write >= STATUS_EVERY_S:
                if station.status["state"] != last_state:
                    print(f"droid-guard: {station.status['state']}: {station.status['distance_mm']:.1f} mm "
                          f"({' with '.join(station.status['pair'])})", file=sys.stderr, flush=True)
                last_state, last_write = station.status["state"], now
                _write_status(cell, station)
    finally:
        if station.faulted:
            station.release()
        timer.close()
        for db in dbs:
            db.close()
    return 0
