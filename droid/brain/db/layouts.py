"""Fixed-layout records of the DROID databases (thesis Tables 3.1–3.3, 4.2–4.3).

Every database is one record in its own POSIX shared-memory object.  Records
are numpy structured dtypes with explicit offsets and little-endian fixed-width
fields, so the byte layout is the same on every host and a C program can attach
to it through the generated header (:mod:`droid.brain.runtime.cheader`).

Each record starts with the same 32-byte :data:`HEADER`:

======  ===========  ==================================================
offset  field        meaning
======  ===========  ==================================================
0       magic        ``DRDB`` (0x42445244 little-endian)
4       version      layout version of this kind (bumped on any change)
6       kind         which layout (``KIND_*`` below)
8       size         record size in bytes, header included
12      writer_pid   pid of the last writer
16      holder_pid   pid holding the semaphore, 0 when free
20      flags        ``FLAG_*`` bits (e.g. recovered after a dead holder)
24      seq          write sequence counter, +1 per locked write
======  ===========  ==================================================

Payload field names follow the thesis tables (x, y, z, R, encoder_pos,
encoder_cmd, busy, homed, cart_time_count, joint_time_count, coord, cmd_mode,
sent, encoder_cmd_ext, encoder_cmd_int); additions are documented per field.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from droid.cli import BadInput

MAGIC = 0x42445244  # b"DRDB" read as little-endian u32
HEADER_SIZE = 32

# Layout kinds
KIND_ARM_STATUS = 1  # Brain, Table 3.1
KIND_ARM_COMMAND = 2  # Brain, Table 3.2
KIND_SENSOR_STATUS = 3  # Brain, Table 3.3
KIND_CTRL_STATUS = 4  # motion controller, Table 4.2
KIND_CTRL_COMMAND = 5  # motion controller, Table 4.3
KIND_PROC_STATUS = 6  # one per running program (droid-cell status)
KIND_JOYSTICK_STATUS = 7  # an analog joystick (thesis §2.6, §3.4, Figure 2.10)
KIND_FT6_STATUS = 8  # a six-axis force/torque sensor (thesis §7.3; droid.subunits.ft)
KIND_FT6_COMMAND = 9  # its Command (Brain): bias, the over-force guard
KIND_FT6_CTRL_COMMAND = 10  # the same on the sensor's host, with the agent's link fields
KIND_GUARD_STATUS = 11  # the collision guard's own Status (droid-guard; docs/guard.md)

# Header flags
FLAG_RECOVERED = 1  # the semaphore was taken over from a dead holder at least once

# Enumerations (thesis §3.3)
JSPACE = 0  # coord: joint space
CARTSPACE = 1  # coord: cartesian space


class CmdMode(IntEnum):
    """Command modes (Command/Status ``cmd_mode``, thesis §3.3 and Table 4.3): the one definition.

    The thesis names the modes but prints no numbers: Tables 3.2 and 4.3 give
    ``cmd_mode`` as "OFF, HOME_MODE, JOG_MODE", and §3.3 adds NORMAL ("its command
    mode becomes NORMAL" after homing).  These numbers are DROID's.  The Brain's
    records, the agents, every task and the Reis servo's command message
    (``servo_params.Mode`` is this class; ``servo_wire`` DSC2/DSS2) use them."""

    OFF = 0
    JOG = 1  # relative encoder counts; works before homing (§3.4)
    HOME = 2  # run the homing routine
    NORMAL = 3  # absolute joint or cartesian target (needs homed)


OFF = CmdMode.OFF  # cmd_mode
JOG_MODE = CmdMode.JOG
HOME_MODE = CmdMode.HOME
NORMAL_MODE = CmdMode.NORMAL
CMD_MODE_NAMES = {int(m): m.name for m in CmdMode}
#: A NORMAL command whose time count (joint_time_count or cart_time_count, by coord) is
#: STOP_TICKS is a *stop* (addition, issue 16): the controller drops what is pending, ends
#: the move in progress where its way-point is and holds there.  Task programs that give
#: up (timeout, stale link, interrupted) write one, so their command is never carried out
#: later (no "orphan moves").  No move command has 0 ticks (droid-move refuses < 1 tick).
STOP_TICKS = 0
COORD_NAMES = {JSPACE: "JOINT", CARTSPACE: "CARTESIAN"}
FALSE = 0
HOMED = 1  # Status.homed (arms); for sensors homed==1 means INVALID data (Table 3.3)

# Proc states
PROC_STARTING = 0
PROC_READY = 1
PROC_STOPPING = 2
PROC_FAILED = 3
PROC_STATE_NAMES = {0: "starting", 1: "ready", 2: "stopping", 3: "failed"}


def _dtype(fields: list[tuple[str, str, tuple | None]], itemsize: int) -> np.dtype:
    """Build a packed, explicitly-offset little-endian dtype; checks alignment."""
    names, formats, offsets = [], [], []
    off = 0
    for name, fmt, shape in fields:
        base = np.dtype(fmt)
        align = base.itemsize
        if off % align:
            raise AssertionError(f"field {name} at {off} is not {align}-aligned")
        names.append(name)
        formats.append((base, shape) if shape else base)
        offsets.append(off)
        off += base.itemsize * (int(np.prod(shape)) if shape else 1)
    if off > itemsize:
        raise AssertionError(f"fields need {off} bytes > itemsize {itemsize}")
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": itemsize})


#: The public name of the dtype builder, for a device package's own layouts (docs/design.md §11):
#: ``record_dtype(HEADER_FIELDS + [...], itemsize)``; its kind number must be new.
record_dtype = _dtype

HEADER_FIELDS = [
    ("magic", "<u4", None),
    ("version", "<u2", None),
    ("kind", "<u2", None),
    ("size", "<u4", None),
    ("writer_pid", "<i4", None),
    ("holder_pid", "<i4", None),
    ("flags", "<u4", None),
    ("seq", "<u8", None),
]
HEADER = _dtype(HEADER_FIELDS, HEADER_SIZE)
HOLDER_PID_OFFSET = 16
WRITER_PID_OFFSET = 12
SEQ_OFFSET = 24

_POSE = [
    ("x", "<f8", None),  # mm, wrt global frame
    ("y", "<f8", None),  # mm
    ("z", "<f8", None),  # mm
    ("R", "<f8", (3, 3)),  # rotation matrix wrt global frame
]

_STATUS = HEADER_FIELDS + _POSE + [
    ("encoder_pos", "<i4", (6,)),  # joint encoder positions wrt home [counts]
    ("encoder_cmd", "<i4", (6,)),  # current joint encoder commands wrt home [counts]
    ("busy", "<i4", None),  # heartbeat ticks left for the current command
    ("homed", "<i4", None),  # HOMED/FALSE (arms); sensors: 1 = data invalid
    ("tick", "<u8", None),  # addition: heartbeat tick of the last refresh
    ("updated_ns", "<i8", None),  # addition: CLOCK_MONOTONIC of the last refresh [ns]
    ("stale", "<u4", None),  # addition: 1 when the link missed >= stale_ticks ticks
    ("fault", "<u4", None),  # addition: fault bits (FAULT_*)
    ("cmd_mode", "<i4", None),  # addition: command mode in force
    ("coord", "<i4", None),  # addition: coordinate mode in force
    ("cmd_id", "<u4", None),  # addition: cmd_id of the command in progress or last finished
    ("cmd_result", "<i4", None),  # addition: CMD_* outcome of that command
]

# Status.cmd_result
CMD_OK = 0  # accepted / in progress / done
CMD_REFUSED = 2  # refused before anything moved (out of limits, unreachable, not homed)
CMD_FAILED = 1  # failed while executing (device fault, timeout)

# Fault bits in Status.fault
FAULT_LINK = 1  # Brain link silent (agent side) / agent silent (remote side)
FAULT_WATCHDOG = 2  # amplifiers latched off by the watchdog
FAULT_SERVO = 4  # servo program silent
FAULT_LIMIT = 8  # a target was clamped at a joint limit
FAULT_BRAKING = 16  # the servo ran out of commands and braked
FAULT_DEVICE = 32  # device driver error (serial port, encoder card)
FAULT_HEARTBEAT = 64  # Brain side: no heartbeat tick for stale_ticks periods (the Status is not being refreshed)
FAULT_FORCE = 128  # an arm: the force/torque sensor on it read more than its guard's limit (droid-ft)
FAULT_COLLISION = 256  # an arm: the collision guard's protective stop (droid.guard, docs/guard.md)
FAULT_GUARD = 512  # an arm in a cell that declares a guard: its Status is stale (droid-guard silent; the planner's rule)
FAULT_NAMES = {
    FAULT_LINK: "link",
    FAULT_WATCHDOG: "watchdog",
    FAULT_SERVO: "servo",
    FAULT_LIMIT: "limit",
    FAULT_BRAKING: "braking",
    FAULT_DEVICE: "device",
    FAULT_HEARTBEAT: "heartbeat",
    FAULT_FORCE: "force",
    FAULT_COLLISION: "collision",
    FAULT_GUARD: "guard",
}
#: The fault bits after which an arm cannot carry out a command: its servo stopped
#: (a latched servo fault, or the servo program silent), its amplifiers latched off by
#: the watchdog ("no further motion is possible without resetting the power", thesis
#: §2.3, §4.1.2), or its device cannot be driven or read.  A task refuses to start a
#: move on such an arm (droid.tasks.arm.BrainArm.check_fresh) and the seam tracker
#: stops on one (droid.tasks.seam.cycle.arm_faults, with the protective stops:
#: FAULTS_STOP_RUN).  Not in it: FAULT_BRAKING alone (the servo ran out of way-points and
#: braked; it follows again when the next command comes), FAULT_LINK and FAULT_HEARTBEAT (the Status goes stale: the stale rules),
#: FAULT_LIMIT (a target clamped).
FAULTS_CANNOT_MOVE = FAULT_SERVO | FAULT_WATCHDOG | FAULT_DEVICE
#: The fault bits that end a tracking or pressing run (droid-seamtrack, droid-contact and the
#: lockstep tracking trial): the ones the arm cannot move with, and the protective stops --
#: FAULT_BRAKING (the servo ran out of way-points and braked, e.g. after a host stall) and
#: FAULT_COLLISION (the guard's stop).  A positioning move rides through a protective stop
#: (droid.tasks.resume); a weld or a press that stopped is a defect, so the run ends as
#: ``fault`` naming the stop (issue 40 item 4; docs/seamtrack.md).
FAULTS_STOP_RUN = FAULTS_CANNOT_MOVE | FAULT_BRAKING | FAULT_COLLISION


def fault_names(bits: int) -> list[str]:
    """The names of the FAULT_* bits set in a Status ``fault`` field, in bit order."""
    bits = int(bits)
    return [name for bit, name in FAULT_NAMES.items() if bits & bit]

ARM_STATUS = _dtype(_STATUS, 224)

SENSOR_STATUS = _dtype(
    _STATUS
    + [
        ("valid_count", "<u4", None),  # addition: valid readings received
        ("invalid_count", "<u4", None),  # addition: readings flagged invalid by the sensor
        ("garbled_count", "<u4", None),  # addition: lines that did not parse
        ("capture_age_us", "<u4", None),  # addition (v2, issue 12): age of the reading's camera frame at
        #                                   updated_ns [us], from the line's stamp; NO_CAPTURE_AGE: unstamped
    ],
    240,
)
#: SENSOR_STATUS.capture_age_us of a reading without a capture stamp.
NO_CAPTURE_AGE = 0xFFFFFFFF

ARM_COMMAND = _dtype(
    HEADER_FIELDS
    + _POSE
    + [
        ("cart_time_count", "<i4", None),  # heartbeat ticks for the cartesian command
        ("joint_time_count", "<i4", None),  # heartbeat ticks for the joint command
        ("encoder_pos", "<i4", (6,)),  # joint encoder commands wrt home [counts]
        ("coord", "<i4", None),  # JSPACE / CARTSPACE
        ("cmd_mode", "<i4", None),  # OFF / JOG_MODE / HOME_MODE / NORMAL_MODE
        ("sent", "<i4", None),  # 1 = written by a task, not yet delivered; 0 = delivered
        ("cmd_id", "<u4", None),  # addition: incremented by a task for every new command
        # version 2 (issue 41): written by the collision guard (droid-guard) each heartbeat tick,
        # not by tasks; relayed to the controller with the rest (ARM6R.command_map)
        ("guard_tick", "<u8", None),  # heartbeat tick of the guard's last pass (0: never)
        ("guard_override", "<f8", None),  # the guard's speed override for this arm, 0..1
    ],
    192,
)

CTRL_STATUS = _dtype(_STATUS, 224)  # Table 4.2: identical to the Brain's Table 3.1

CTRL_COMMAND = _dtype(
    HEADER_FIELDS
    + _POSE
    + [
        ("cart_time_count", "<i4", None),  # the Brain Command's, copied in (droid-agent)
        ("joint_time_count", "<i4", None),  # the Brain Command's, copied in
        ("encoder_cmd_ext", "<i4", (6,)),  # gross joint command [counts], external: the Brain's, copied in
        ("encoder_cmd_int", "<i4", (6,)),  # interpolated way-point [counts], internal: droid-planner's
        ("coord", "<i4", None),
        ("cmd_mode", "<i4", None),
        ("sent", "<i4", None),
        ("cmd_id", "<u4", None),  # addition: id of the Brain command copied in
        ("brain_tick", "<u8", None),  # addition: last heartbeat tick relayed by the agent
        ("link_alive", "<u4", None),  # addition: 0 once the Brain link missed >= 3 ticks
        ("plan_id", "<u4", None),  # addition: cmd_id the planner last accepted
        ("planner_tick", "<u8", None),  # addition: last relayed tick the planner processed
        ("guard_tick", "<u8", None),  # version 2 (issue 41): the Brain Command's, copied in
        ("guard_override", "<f8", None),  # version 2: the Brain Command's, copied in
        # version 3 (docs/safety.md finding 11): droid-planner's own move, in fields no other
        # program writes.  The planner used to write its target and ticks left back into
        # encoder_cmd_ext / joint_time_count, which droid-agent overwrites with the Brain's
        # values every tick: a reader between the two writes (a servo agent bridging a late
        # planner) took the Brain's last joint target for the planner's.
        ("plan_ext", "<i4", (6,)),  # the planner's move target [counts] (a cartesian command's IK)
        ("plan_time_count", "<i4", None),  # heartbeat ticks left of the planner's move
    ],
    272,
)

PROC_STATUS = _dtype(
    HEADER_FIELDS
    + [
        ("name", "S32", None),  # program name, e.g. b"droid-remote arm1"
        ("pid", "<i4", None),
        ("state", "<i4", None),  # PROC_* above
        ("last_tick", "<u8", None),  # last heartbeat tick seen (0 if not tick-driven)
        ("updated_ns", "<i8", None),  # CLOCK_MONOTONIC of last update [ns]
        ("cycles", "<u8", None),  # loop cycles run
        ("overruns", "<u8", None),  # missed deadlines (tick-driven programs: missed ticks)
        ("lateness_max_ns", "<i8", None),  # worst wake-up lateness [ns]; LATENESS_NO_RECORD: none kept
        ("bad_frames", "<u8", None),  # malformed messages received and dropped (version 2)
        ("missed_pct", "<f4", None),  # share of its periods missed in the last window [%] (version 3)
        ("lagging", "<u4", None),  # 1 while it cannot keep its rate (missed_pct >= LAG_PCT; version 3)
    ],
    128,
)


#: axes and buttons a joystick record holds (the thesis's Thrustmaster: 2 analog
#: axes and 8 digital inputs, §2.6; a USB stick has more)
JOYSTICK_AXES = 8
JOYSTICK_BUTTONS = 16

JOYSTICK_STATUS = _dtype(
    HEADER_FIELDS
    + [
        ("axes", "<f8", (JOYSTICK_AXES,)),  # deflection, -1..1 (0 = centred); unused axes 0
        ("buttons", "<u1", (JOYSTICK_BUTTONS,)),  # 1 = pressed
        ("valid", "<u4", None),  # 1 = the device is open and its state is known
        ("events", "<u4", None),  # device events read (wraps)
        ("tick", "<u8", None),  # heartbeat tick of the last refresh
        ("updated_ns", "<i8", None),  # CLOCK_MONOTONIC of the last refresh [ns]
        ("stale", "<u4", None),  # 1 when the link missed >= stale_ticks ticks
        ("fault", "<u4", None),  # FAULT_* bits (FAULT_DEVICE: the device could not be read)
        ("n_axes", "<u4", None),  # axes the device has (<= JOYSTICK_AXES)
        ("n_buttons", "<u4", None),  # buttons the device has (<= JOYSTICK_BUTTONS)
    ],
    160,
)


FT6_STATUS = _dtype(
    HEADER_FIELDS
    + [
        ("force_N", "<f8", (3,)),  # Fx Fy Fz in the sensor frame [N] (after the software bias)
        ("torque_Nm", "<f8", (3,)),  # Tx Ty Tz about the sensor frame's origin [N m]
        ("force_tool_N", "<f8", (3,)),  # the same force in the tool frame [N] (cell file tool_pose)
        ("torque_tool_Nm", "<f8", (3,)),  # the torque about the tool frame's origin, in it [N m]
        ("sample_ns", "<i8", None),  # CLOCK_MONOTONIC when the reading's record arrived [ns]: the
        #                              time the reading describes
        ("sample_age_ms", "<f8", None),  # age of that record at updated_ns [ms]
        ("tick", "<u8", None),  # heartbeat tick of the last refresh (Brain side)
        ("updated_ns", "<i8", None),  # CLOCK_MONOTONIC of the last refresh [ns]
        ("rdt_seq", "<u4", None),  # RDT sequence number of the reading's record
        ("ft_seq", "<u4", None),  # the device's internal sample number of that record
        ("status_word", "<u4", None),  # the device's 32-bit status code in that record
        ("valid", "<u4", None),  # 1 = calibrated, streaming, the newest record within stale_ticks
        ("saturated", "<u4", None),  # 1 = the device flags saturation (status bit 0x00020000)
        ("biased", "<u4", None),  # 1 = a software bias was set in this stream
        ("dropped", "<u4", None),  # records lost (gaps in rdt_seq), since start (wraps)
        ("out_of_order", "<u4", None),  # records older than (or equal to) one already applied
        ("bad_datagrams", "<u4", None),  # datagrams that were not one 36-byte record
        ("records", "<u4", None),  # records applied (wraps)
        ("stale", "<u4", None),  # 1 when the link (Brain) or the records (subunit) went silent
        ("fault", "<u4", None),  # FAULT_* bits (FAULT_DEVICE: no calibration, no records)
    ],
    208,
)

_FT6_COMMAND_FIELDS = [
    ("guard_force_n", "<f8", None),  # over-force guard on the sensor's arm [N]; 0 = off
    ("bias_id", "<u4", None),  # a new value asks the sensor to bias (zero) its readings now
    ("sent", "<i4", None),  # 1 = written by a task, not yet delivered; 0 = delivered (Table 3.2)
    ("cmd_id", "<u4", None),  # incremented by a task for every new command
]
FT6_COMMAND = _dtype(HEADER_FIELDS + _FT6_COMMAND_FIELDS, 64)
FT6_CTRL_COMMAND = _dtype(
    HEADER_FIELDS
    + _FT6_COMMAND_FIELDS
    + [
        ("link_alive", "<u4", None),  # 0 once the Brain link went silent (the agent's rule)
        ("brain_tick", "<u8", None),  # last heartbeat tick relayed by the agent
    ],
    64,
)

#: droid-guard's Status (issue 41, docs/guard.md): ``/droid.<cell>.guard.status``, written by
#: droid-guard on every heartbeat tick it runs a pass (the lockstep station keeps the same fields)
GUARD_ARMS = 8  # arms a guard Status holds (the override per arm)
GUARD_NAME = "S16"  # an arm's or a body's name (``arm1``, ``link_4``, ``fixture``, ``floor``)
GUARD_CLEAR, GUARD_SLOWING, GUARD_STOPPED = 0, 1, 2  # GUARD_STATUS.state
GUARD_STATE_NAMES = {GUARD_CLEAR: "clear", GUARD_SLOWING: "slowing", GUARD_STOPPED: "stopped"}
GUARD_STATUS = _dtype(
    HEADER_FIELDS
    + [
        ("tick", "<u8", None),  # heartbeat tick of the last pass (freshness: the planners' stale rule)
        ("updated_ns", "<i8", None),  # CLOCK_MONOTONIC of the last pass [ns]
        ("cycles", "<u8", None),  # passes run
        ("distance_mm", "<f8", None),  # least distance between checked bodies now [mm] (<= 0: in collision)
        ("ahead_mm", "<f8", None),  # least distance over the way-points ahead [mm]
        ("closing_mm_s", "<f8", None),  # the closing speed taken [mm/s]
        ("separation_mm", "<f8", None),  # S_p, the protective separation distance [mm]
        ("cycle_us", "<f8", None),  # the last pass's time [us]
        ("cycle_max_us", "<f8", None),  # the worst pass's time since start [us]
        ("state", "<u4", None),  # GUARD_CLEAR / GUARD_SLOWING / GUARD_STOPPED
        ("trips", "<u4", None),  # protective stops since start
        ("n_arms", "<u4", None),  # arms guarded (the first n of ``arms`` and ``override``)
        ("stale_ticks", "<u4", None),  # the cell's [guard] stale_ticks: older than this is stale
        ("pairs", "<u4", None),  # pairs of bodies checked
        ("kernel", "<u4", None),  # 1: the pass ran compiled (droid._guard), 0: the Python reference
        ("a_arm", GUARD_NAME, None),  # the closest pair: one body's owner (an arm, or "fixture") ...
        ("a_body", GUARD_NAME, None),  # ... and its name (link_4, tool, sensor, workpiece, a fixture's)
        ("b_arm", GUARD_NAME, None),
        ("b_body", GUARD_NAME, None),
        ("arms", GUARD_NAME, (GUARD_ARMS,)),  # the arms' subunit names
        ("override", "<f8", (GUARD_ARMS,)),  # the speed override written into each arm's Command, 0..1
        # version 2 (issue 41 item 5, droid-web/droid-foxglove draw the closest pair): the closest
        # points of the closest pair now [mm, global frame], on body a and on body b (on a capsule's
        # axis, on or in a box); NaN when nothing is judged
        ("a_point_mm", "<f8", (3,)),
        ("b_point_mm", "<f8", (3,)),
    ],
    432,
)


@dataclass(frozen=True)
class Layout:
    """A versioned record layout: kind, version and dtype."""

    name: str
    kind: int
    version: int
    dtype: np.dtype
    c_name: str

    @property
    def size(self) -> int:
        return self.dtype.itemsize


ARM_STATUS_LAYOUT = Layout("arm_status", KIND_ARM_STATUS, 1, ARM_STATUS, "droid_arm_status")
ARM_COMMAND_LAYOUT = Layout("arm_command", KIND_ARM_COMMAND, 2, ARM_COMMAND, "droid_arm_command")
SENSOR_STATUS_LAYOUT = Layout("sensor_status", KIND_SENSOR_STATUS, 2, SENSOR_STATUS, "droid_sensor_status")
CTRL_STATUS_LAYOUT = Layout("ctrl_status", KIND_CTRL_STATUS, 1, CTRL_STATUS, "droid_ctrl_status")
CTRL_COMMAND_LAYOUT = Layout("ctrl_command", KIND_CTRL_COMMAND, 3, CTRL_COMMAND, "droid_ctrl_command")
#: ``lateness_max_ns`` of a program that keeps no lateness record (it neither runs on its own
#: timer nor reads ticks stamped on its own machine's clock)
LATENESS_NO_RECORD = -1

PROC_STATUS_LAYOUT = Layout("proc_status", KIND_PROC_STATUS, 3, PROC_STATUS, "droid_proc_status")
JOYSTICK_STATUS_LAYOUT = Layout("joystick_status", KIND_JOYSTICK_STATUS, 1, JOYSTICK_STATUS,
                                "droid_joystick_status")
FT6_STATUS_LAYOUT = Layout("ft6_status", KIND_FT6_STATUS, 1, FT6_STATUS, "droid_ft6_status")
FT6_COMMAND_LAYOUT = Layout("ft6_command", KIND_FT6_COMMAND, 1, FT6_COMMAND, "droid_ft6_command")
FT6_CTRL_COMMAND_LAYOUT = Layout("ft6_ctrl_command", KIND_FT6_CTRL_COMMAND, 1, FT6_CTRL_COMMAND,
                                 "droid_ft6_ctrl_command")
GUARD_STATUS_LAYOUT = Layout("guard_status", KIND_GUARD_STATUS, 2, GUARD_STATUS, "droid_guard_status")

LAYOUTS = {
    lay.kind: lay
    for lay in (
        ARM_STATUS_LAYOUT,
        ARM_COMMAND_LAYOUT,
        SENSOR_STATUS_LAYOUT,
        CTRL_STATUS_LAYOUT,
        CTRL_COMMAND_LAYOUT,
        PROC_STATUS_LAYOUT,
        JOYSTICK_STATUS_LAYOUT,
        FT6_STATUS_LAYOUT,
        FT6_COMMAND_LAYOUT,
        FT6_CTRL_COMMAND_LAYOUT,
        GUARD_STATUS_LAYOUT,
    )
}


def new_record(layout: Layout) -> np.ndarray:
    """A zeroed 0-d record of ``layout`` with its header filled in and R = identity."""
    rec = np.zeros((), dtype=layout.dtype)
    rec["magic"] = MAGIC
    rec["version"] = layout.version
    rec["kind"] = layout.kind
    rec["size"] = layout.size
    if "R" in layout.dtype.names:
        rec["R"] = np.eye(3)
    return rec


_HEADER_FRONT = struct.Struct("<IHHI")  # magic, version, kind, size: HEADER_FIELDS' first four


def check_header(buf, layout: Layout, what: str) -> None:
    """Raise :class:`LayoutError` unless ``buf`` starts with ``layout``'s header."""
    if len(buf) < HEADER_SIZE:
        raise LayoutError(f"{what}: {len(buf)} bytes is too short for a DROID record")
    magic, version, kind, size = _HEADER_FRONT.unpack_from(buf)
    if (magic == MAGIC and kind == layout.kind and version == layout.version
            and size == layout.size and len(buf) >= size):
        return  # the common case, in one struct call (every tick of every link: issue 28 item 2)
    hdr = np.frombuffer(buf, dtype=HEADER, count=1)[0]
    if int(hdr["magic"]) != MAGIC:
        raise LayoutError(f"{what}: bad magic 0x{int(hdr['magic']):08x} (not a DROID record)")
    if int(hdr["kind"]) != layout.kind:
        other = LAYOUTS.get(int(hdr["kind"]))
        found = other.name if other else f"kind {int(hdr['kind'])}"
        raise LayoutError(f"{what}: holds a {found} record, expected {layout.name}")
    if int(hdr["version"]) != layout.version:
        raise LayoutError(
            f"{what}: layout version {int(hdr['version'])} of {layout.name}, "
            f"this program speaks version {layout.version}"
        )
    if int(hdr["size"]) != layout.size or len(buf) < layout.size:
        raise LayoutError(f"{what}: record size {int(hdr['size'])} bytes, expected {layout.size}")


class LayoutError(BadInput):
    """A record's magic, kind, version or size does not match this program's layout."""


def byte_runs(src_dtype, dst_dtype, field_map: dict[str, str]) -> tuple | None:
    """The copy ``dst[field_map[f]] = src[f]`` as byte ranges (source offset, destination offset,
    bytes), neighbours merged -- or None unless each pair has the very same type (then a field's
    assignment is a copy of its bytes, the same bits; issue 28 item 2: the agent's command copy; issue 44: the remote's reply)."""
    runs: list[list[int]] = []
    for s, d in sorted(field_map.items(), key=lambda sd: src_dtype.fields[sd[0]][1]):
        (st, so), (dt, do) = src_dtype.fields[s][:2], dst_dtype.fields[d][:2]
        if st != dt:
            return None
        if runs and runs[-1][0] + runs[-1][2] == so and runs[-1][1] + runs[-1][2] == do:
            runs[-1][2] += st.itemsize
        else:
            runs.append([so, do, st.itemsize])
    return tuple(tuple(r) for r in runs)
