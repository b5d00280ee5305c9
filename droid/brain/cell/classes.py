"""Subunit classes as data (thesis §3.2: "each ... a separate entity with a known interface").

A subunit's ``class`` in the cell file names one :class:`SubunitClass`: its
layout definitions (the Brain's Status and, for a commandable subunit, its
Command; the subunit side's own records), the fields ``droid-remote`` copies
from the agent's reply into the Brain's Status, the fields ``droid-snoop``
prints, and the drivers its programs open.  A class is declared by a device
package (``droid/subunits/<pkg>/device.py``) and registered in the device
registry (:mod:`droid.brain.cell.registry`; its view ``registry.classes()``).
The Brain (databases, remote), ``droid-snoop`` and ``droid-cheader`` read it and
never name a class.

class          Brain areas                subunit areas                 drivers (URL schemes)
=============  =========================  ============================  ===========================
``arm6r``      status (3.1), command (3.2) ctrl_status (4.2),            shm:// VME map, serial port
                                          ctrl_command (4.3)
``line_laser`` status (3.3)               ctrl_status (3.3)             serial line, shm:// DSP
``joystick``   status (joystick_status)   ctrl_status (joystick_status) js://, evdev://
``ft6``        status (ft6_status)        ctrl_status (ft6_status)      netft:// (RDT over UDP)
=============  =========================  ============================  ===========================
=======
The Brain defines the two thesis interfaces here, which several packages serve:
``arm6r`` (Tables 3.1-3.2, 4.2-4.3: the Reis, the GMF1) and ``line_laser``
(Table 3.3: the MVS, the tool-tip sensor).  Other classes live in their package
(``joystick``: :mod:`droid.subunits.joystick.device`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from droid.brain.db.layouts import (
    ARM_COMMAND_LAYOUT,
    ARM_STATUS_LAYOUT,
    CMD_MODE_NAMES,
    CTRL_COMMAND_LAYOUT,
    CTRL_STATUS_LAYOUT,
    FAULT_NAMES,
    SENSOR_STATUS_LAYOUT,
    Layout,
)


@dataclass(frozen=True)
class SubunitClass:
    """One class of subunit: layouts, copied fields, snoop fields, drivers."""

    name: str
    description: str
    brain: dict[str, Layout]  # Brain area -> layout ("status" always; "command" if commandable)
    local: dict[str, Layout]  # subunit-side area -> layout ("ctrl_status" always)
    copy_fields: tuple[str, ...]  # reply fields droid-remote copies into the Brain Status
    snoop_fields: tuple[str, ...]  # Status fields droid-snoop prints (besides subunit, tick, stale)
    kinematic: bool = False  # an arm: needs `robot`; droid-remote adds the pose by FK (§4.1.8)
    drivers: dict[str, str] = field(default_factory=dict)  # URL scheme -> "module:Class" (lazy)
    # a commandable class: the agent copies these Brain Command fields into the local
    # ctrl_command (Brain field -> local field; droid.subunits.agent.CommandCopier)
    command_map: dict[str, str] = field(default_factory=dict)

    @property
    def commandable(self) -> bool:
        return "command" in self.brain


ARM6R = SubunitClass(
    name="arm6r",
    description="6R arm of the OPW class (thesis Tables 3.1-3.2, 4.2-4.3)",
    brain={"status": ARM_STATUS_LAYOUT, "command": ARM_COMMAND_LAYOUT},
    local={"ctrl_status": CTRL_STATUS_LAYOUT, "ctrl_command": CTRL_COMMAND_LAYOUT},
    copy_fields=("encoder_pos", "encoder_cmd", "busy", "homed", "fault", "cmd_mode", "coord",
                 "cmd_id", "cmd_result"),
    snoop_fields=("x", "y", "z", "R", "encoder_pos", "encoder_cmd", "busy", "homed", "cmd_mode", "fault"),
    kinematic=True,
    # Brain Command (Table 3.2) -> controller Command (Table 4.3)
    command_map={"x": "x", "y": "y", "z": "z", "R": "R", "cart_time_count": "cart_time_count",
                 "joint_time_count": "joint_time_count", "encoder_pos": "encoder_cmd_ext", "coord": "coord",
                 "cmd_mode": "cmd_mode", "sent": "sent", "cmd_id": "cmd_id",
                 "guard_tick": "guard_tick", "guard_override": "guard_override"},  # the collision guard's (issue 41)
)

LINE_LASER = SubunitClass(
    name="line_laser",
    description="line-laser sensor reporting x, y, roll (thesis Table 3.3)",
    brain={"status": SENSOR_STATUS_LAYOUT},
    local={"ctrl_status": SENSOR_STATUS_LAYOUT},
    copy_fields=("x", "y", "z", "R", "homed", "fault", "valid_count", "invalid_count", "garbled_count"),
    snoop_fields=("x", "y", "z", "R", "encoder_pos", "encoder_cmd", "busy", "homed", "cmd_mode", "fault",
                  "invalid", "valid_count", "invalid_count", "garbled_count"),
)


def field_json(rec, name: str):
    """Status field ``name`` of record ``rec`` as a JSON value (snoop): numbers rounded, arrays
    as lists, names for codes; ``invalid`` is Table 3.3's reading of ``homed`` for sensors."""
    if name == "invalid":
        return bool(rec["homed"])
    value = rec[name]
    if name == "cmd_mode":
        return CMD_MODE_NAMES.get(int(value), str(int(value)))
    if name == "fault":
        return [n for bit, n in FAULT_NAMES.items() if int(value) & bit]
    if name == "R":
        return [[round(float(v), 6) for v in row] for row in value]
    if name in ("x", "y", "z"):
        return round(float(value), 4)
    if name == "axes":
        return [round(float(v), 4) for v in value]
    if getattr(getattr(value, "dtype", None), "kind", "") == "f":  # N, N m, ms: floats, never truncated
        return [round(float(v), 6) for v in value] if value.shape != () else round(float(value), 6)
    if getattr(value, "shape", ()) != ():
        return [int(v) for v in value]
    return int(value)
