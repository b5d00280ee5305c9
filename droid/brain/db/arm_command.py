"""Arm commands, written into a Brain Command record (thesis Table 3.2, §3.3): the one place.

Every move is timed in heartbeat ticks, as the record holds it ("the number of
heartbeat counts needed to complete it", §3.3): ``joint_time_count`` for a joint
command, ``cart_time_count`` for a cartesian one.  Task programs (BrainArm), the
lockstep arms and the experiments write through these functions; a caller holding
seconds converts once with :func:`ticks_for`.  Each write sets the next ``cmd_id``
and ``sent = 1`` under one lock (:func:`droid.brain.db.databases.write_command`) and
returns the ``cmd_id``.
"""
from __future__ import annotations

import numpy as np

from droid.brain.db.databases import write_command
from droid.brain.db.layouts import CARTSPACE, HOME_MODE, JOG_MODE, JSPACE, NORMAL_MODE, STOP_TICKS


def ticks_for(seconds: float, heartbeat_hz: float) -> int:
    """``seconds`` [s] as whole heartbeat ticks (rounded; no validation: see BrainArm.ticks_for)."""
    return int(round(seconds * heartbeat_hz))


def joint(command, counts, ticks: int, mode: int = NORMAL_MODE) -> int:
    """A joint command: six encoder counts (absolute wrt home; JOG: relative) in ``ticks``."""
    return write_command(command, encoder_pos=np.asarray(counts, np.int32), joint_time_count=int(ticks),
                         coord=JSPACE, cmd_mode=mode)


def jog(command, delta_counts, ticks: int = 1) -> int:
    """A relative joint command [encoder counts] (works before homing, §3.4)."""
    return joint(command, delta_counts, ticks, mode=JOG_MODE)


def cart(command, T, ticks: int) -> int:
    """A cartesian command: the WCP pose ``T`` (4x4, global frame, mm) in ``ticks``."""
    T = np.asarray(T, float)
    return write_command(command, x=T[0, 3], y=T[1, 3], z=T[2, 3], R=T[:3, :3], cart_time_count=int(ticks),
                         coord=CARTSPACE, cmd_mode=NORMAL_MODE)


def home(command) -> int:
    """Start homing (the Home program, §3.4)."""
    return write_command(command, cmd_mode=HOME_MODE, coord=JSPACE)


def stop(command) -> int:
    """A stop (STOP_TICKS, issue 16): the move in progress ends where it is."""
    return write_command(command, coord=JSPACE, cmd_mode=NORMAL_MODE, joint_time_count=STOP_TICKS,
                         cart_time_count=STOP_TICKS)


def set_normal(command) -> None:
    """After homing the command mode becomes NORMAL (thesis §3.3); no new command (no cmd_id)."""
    with command.locked() as c:
        c["cmd_mode"] = NORMAL_MODE
        command.mark_written()
