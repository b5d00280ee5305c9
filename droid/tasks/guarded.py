"""A task's move checked against the collision guard's bodies before it is written (issue 41 item 3).

Where the cell declares a ``[guard]`` table (docs/guard.md), :func:`refuse_colliding_move`
samples the move's joint path against every other arm: where it stands (its Brain Status
``encoder_pos``) or, when it is busy on a joint move, along that move toward its Brain Command's
target (``encoder_pos`` of the Command, JSPACE) over its ``busy`` ticks; and raises
:class:`BadInput` -- exit 2, nothing written, the arm never moves -- with the one line of
:func:`droid.guard.refuse.check_move`.  A cell without a ``[guard]`` table is not checked.
"""
from __future__ import annotations

import numpy as np

from droid.brain.databases import open_brain
from droid.brain.layouts import JSPACE
from droid.cli import BadInput
from droid.guard.cell import guard_scene, guard_table
from droid.guard.refuse import check_move
from droid.guard.ssm import ssm_params
from droid.kinematics import load_robot


def _other_arm(cell, name: str) -> tuple[np.ndarray, tuple | None]:
    """An arm's joints now [deg] and (its move's target [deg], seconds left) or None."""
    sub = cell.subunit(name)
    gearing = load_robot(sub.robot).gearing
    st_db, cmd_db = open_brain(cell, sub, "status"), open_brain(cell, sub, "command")
    try:
        st, cmd = st_db.read(), cmd_db.read()
    finally:
        st_db.close()
        cmd_db.close()
    q = gearing.counts_to_joints(np.asarray(st["encoder_pos"], float))
    busy = int(st["busy"])
    if busy > 0 and int(cmd["coord"]) == JSPACE:
        return q, (gearing.counts_to_joints(np.asarray(cmd["encoder_pos"], float)), busy / cell.heartbeat_hz)
    return q, None


def refuse_colliding_move(cell, arm: str, q_from_deg, q_to_deg, seconds: float) -> None:
    """BadInput with the guard's line when the move would bring a body closer than C + Z (docs/guard.md)."""
    if "guard" not in cell.raw:
        return
    scene = guard_scene(cell)
    p = ssm_params(guard_table(cell).get("ssm"), str(cell.path))
    now, moves = {}, {}
    for name in scene.arms:
        if name == arm:
            continue
        now[name], move = _other_arm(cell, name)
        if move is not None:
            moves[name] = move
    line = check_move(scene, arm, q_from_deg, q_to_deg, seconds, now, moves, p.clearance_mm + p.uncertainty_mm)
    if line:
        raise BadInput(line)
