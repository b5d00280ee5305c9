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

The decision is pure (:func:`wait_clear_step`, on the other arms' records read by
:func:`other_arm_of`), so the same rule runs on a live cell here and in lockstep, on virtual
time (tests/guard/test_wait_clear.py: two arms in overlapping regions of a held-out cell,
docs/guard.md §9).
"""
from __future__ import annotations

import sys
import time

import numpy as np

from droid.brain.db.databases import open_brain
from droid.brain.db.layouts import JSPACE
from droid.cli import BadInput
from droid.guard.cell import guard_scene, guard_table
from droid.guard.refuse import check_move
from droid.guard.ssm import ssm_params
from droid.kinematics import load_robot

#: :func:`wait_clear_step`'s answers: write the move; hold (check again on a later tick); refuse it
GO, HOLD, REFUSE = "go", "hold", "refuse"


def other_arm_of(st, cmd, gearing, heartbeat_hz: float) -> tuple[np.ndarray, tuple | None, bool]:
    """From an arm's Brain Status ``st`` and Command ``cmd``: its joints now [deg], (its joint
    move's target [deg], seconds left) or None, and whether it is busy on any move (a Cartesian
    one's path is not known here: it stands)."""
    q = gearing.counts_to_joints(np.asarray(st["encoder_pos"], float))
    busy = int(st["busy"])
    if busy > 0 and int(cmd["coord"]) == JSPACE:
        return q, (gearing.counts_to_joints(np.asarray(cmd["encoder_pos"], float)), busy / heartbeat_hz), True
    return q, None, busy > 0


def _other_arm(cell, name: str, gearing) -> tuple[np.ndarray, tuple | None, bool]:
    """:func:`other_arm_of` an arm of the running cell (its Brain databases read once)."""
    sub = cell.subunit(name)
    st_db, cmd_db = open_brain(cell, sub, "status"), open_brain(cell, sub, "command")
    try:
        st, cmd = st_db.read(), cmd_db.read()
    finally:
        st_db.close()
        cmd_db.close()
    return other_arm_of(st, cmd, gearing, cell.heartbeat_hz)


def wait_clear_step(scene, arm: str, q_from_deg, q_to_deg, seconds: float, others: dict, limit_mm: float,
                    waited_s: float, wait_s: float, holding: bool) -> tuple[str, str | None]:
    """One look at the other arms (the module docstring's rule): ``(GO, None)``, ``(HOLD, line)``
    -- ``line`` the reason, None while already holding for a busy arm -- or ``(REFUSE, line)``.
    ``others``: arm -> :func:`other_arm_of`; ``limit_mm``: C + Z; ``waited_s``: the time since
    the first look [s]; ``holding``: an earlier look said HOLD with a reason."""
    now = {n: o[0] for n, o in others.items()}
    moves = {n: o[1] for n, o in others.items() if o[1] is not None}
    busy = [n for n, o in others.items() if o[2]]
    if holding and busy and waited_s < wait_s:  # holding: until every other arm's move has ended
        return HOLD, None
    line = check_move(scene, arm, q_from_deg, q_to_deg, seconds, now, moves, limit_mm)
    if not line:
        return GO, None
    if not busy or waited_s >= wait_s:
        return REFUSE, line + (f"; the region did not clear in {waited_s:.1f} s" if holding else "")
    return HOLD, line


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
        state = {name: _other_arm(cell, name, gearing[name]) for name in others}
        waited = time.monotonic() - start
        action, line = wait_clear_step(scene, arm, q_from_deg, q_to_deg, seconds, state,
                                       p.clearance_mm + p.uncertainty_mm, waited, wait_s, said)
        if action == GO:
            return waited if said else 0.0
        if action == REFUSE:
            raise BadInput(line)
        if not said:
            who = " and ".join(f"{n}'s move" for n, o in state.items() if o[2])
            print(f"{arm}: holding until {who} clears the region ({line})", file=err, flush=True)
            said = True
        time.sleep(1.0 / cell.heartbeat_hz)
