"""A task's move checked against the collision guard's bodies before it is written (issue 41 items 3, 4).

Where the cell declares a ``[guard]`` table (docs/guard.md), :func:`refuse_colliding_move`
samples the move's joint path against every other arm: where it stands (its Brain Status
``encoder_pos``) or, when it is busy on a joint move, along that move toward its Brain Command's
target (``encoder_pos`` of the Command, JSPACE) over its ``busy`` ticks; and raises
:class:`BadInput` -- exit 2, nothing written, the arm never moves -- with the one line of
:func:`droid.guard.refuse.check_move`.  A cell without a ``[guard]`` table is not checked.

**Coordination** (item 4): with ``wait_s > 0`` (droid-move ``--wait-clear S``) a move that would
collide while another arm is busy on a move of its own is not refused at once: the task holds
until that arm's move has ended (its Status ``busy`` 0: one arm holds until the other's move
ends), says so once on stderr (``arm1: holding until gmf1's move clears the region (would
collide: ...)``), and checks again against where it came to rest -- then the move goes, or is
refused as without waiting if it still collides (exit 2, the line ends ``; the region did not
clear in S s``).  ``wait_s`` seconds without the other arms coming to rest: the same refusal.
Going only once the other move has ended, not as soon as the time-aligned paths pass C + Z,
keeps the two arms from closing at speed, where the guard's S_p (the speed terms) would slow or
stop them.  A move against an arm at rest is refused at once: nothing would clear it.  The arm
never moves before the check passes.
"""
from __future__ import annotations

import sys
import time

import numpy as np

from droid.brain.databases import open_brain
from droid.brain.layouts import JSPACE
from droid.cli import BadInput
from droid.guard.cell import guard_scene, guard_table
from droid.guard.refuse import check_move
from droid.guard.ssm import ssm_params
from droid.kinematics import load_robot


def _other_arm(cell, name: str, gearing) -> tuple[np.ndarray, tuple | None, bool]:
    """An arm's joints now [deg], (its joint move's target [deg], seconds left) or None, and
    whether it is busy on any move (a Cartesian one's path is not known here: it stands)."""
    sub = cell.subunit(name)
    st_db, cmd_db = open_brain(cell, sub, "status"), open_brain(cell, sub, "command")
    try:
        st, cmd = st_db.read(), cmd_db.read()
    finally:
        st_db.close()
        cmd_db.close()
    q = gearing.counts_to_joints(np.asarray(st["encoder_pos"], float))
    busy = int(st["busy"])
    if busy > 0 and int(cmd["coord"]) == JSPACE:
        return q, (gearing.counts_to_joints(np.asarray(cmd["encoder_pos"], float)), busy / cell.heartbeat_hz), True
    return q, None, busy > 0


def refuse_colliding_move(cell, arm: str, q_from_deg, q_to_deg, seconds: float, wait_s: float = 0.0,
                          err=None) -> float:
    """BadInput with the guard's line when the move would bring a body closer than C + Z
    (docs/guard.md); with ``wait_s`` > 0, hold while a busy arm is the reason (see the module's
    docstring).  Returns the seconds held (0.0 when the move was clear at once)."""
    if "guard" not in cell.raw:
        return 0.0
    err = err or sys.stderr
    scene = guard_scene(cell)
    p = ssm_params(guard_table(cell).get("ssm"), str(cell.path))
    others = [n for n in scene.arms if n != arm]
    gearing = {n: load_robot(cell.subunit(n).robot).gearing for n in others}
    start = time.monotonic()
    said = False
    while True:
        now, moves, busy = {}, {}, []
        for name in others:
            now[name], move, is_busy = _other_arm(cell, name, gearing[name])
            if move is not None:
                moves[name] = move
            if is_busy:
                busy.append(name)
        waited = time.monotonic() - start
        if said and busy and waited < wait_s:  # holding: until every other arm's move has ended
            time.sleep(1.0 / cell.heartbeat_hz)
            continue
        line = check_move(scene, arm, q_from_deg, q_to_deg, seconds, now, moves,
                          p.clearance_mm + p.uncertainty_mm)
        if not line:
            return waited if said else 0.0
        if not busy or waited >= wait_s:
            raise BadInput(line + (f"; the region did not clear in {waited:.1f} s" if said else ""))
        if not said:
            who = " and ".join(f"{n}'s move" for n in busy)
            print(f"{arm}: holding until {who} clears the region ({line})", file=err, flush=True)
            said = True
        time.sleep(1.0 / cell.heartbeat_hz)
