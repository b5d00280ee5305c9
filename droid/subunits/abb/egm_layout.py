"""The EGM link's own record, ``/droid.<cell>.<sub>.egm`` (an addition beside Table 4.2; docs/abb.md).

The controller's Status record (Table 4.2) carries what every arm reports -- encoder
positions and commands, homed, busy, faults.  What only an EGM link has lives here, written by
``droid-egm`` each heartbeat period: the controller's feedback and planned joints [deg], the
target sent [deg], motor / RAPID / MCI state and the convergence flag as EGM reports them (the
enum numbers of egm.proto), the newest sample's sequence number, controller time and age, and
the link's counters.  The record is this package's: its kind is not in
``droid.brain.db.layouts.LAYOUTS`` (the Brain never reads it; ``droid-cheader`` does not emit it).
"""
from __future__ import annotations

from droid.brain.db.layouts import HEADER_FIELDS, Layout, _dtype

KIND_EGM_STATUS = 32  # this package's record kind (outside droid.brain.db.layouts' numbering, 1..7)

#: the link counters, in record order (docs/abb.md "Counters")
COUNTERS = ("accepted", "lost", "late", "duplicated", "reordered", "malformed", "oversized", "foreign",
            "reconnects", "replies")

EGM_STATUS = _dtype(
    HEADER_FIELDS
    + [
        ("feedback_deg", "<f8", (6,)),  # EgmRobot.feedBack.joints of the newest sample [deg]
        ("planned_deg", "<f8", (6,)),  # EgmRobot.planned.joints (the controller's reference) [deg]
        ("target_deg", "<f8", (6,)),  # the joint target droid-egm sends (EgmSensor.planned) [deg]
        ("motor_state", "<u4", None),  # EgmMotorState: 0 undefined, 1 on, 2 off
        ("rapid_state", "<u4", None),  # EgmRapidCtrlExecState: 0 undefined, 1 stopped, 2 running
        ("mci_state", "<u4", None),  # EgmMCIState: 0 undefined, 1 error, 2 stopped, 3 running
        ("convergence", "<u4", None),  # EgmRobot.mciConvergenceMet (1 = the arm is on the target)
        ("seqno", "<u4", None),  # EgmHeader.seqno of the newest sample
        ("tm_ms", "<u4", None),  # EgmHeader.tm of the newest sample (controller clock) [ms]
        ("sample_age_us", "<u4", None),  # age of the newest sample when written [us] (saturates)
        ("source_port", "<u4", None),  # UDP port the controller sends from (replies go there)
        ("updated_ns", "<i8", None),  # CLOCK_MONOTONIC (or virtual time) of the write [ns]
    ]
    + [(name, "<u8", None) for name in COUNTERS],
    296,
)
EGM_STATUS_LAYOUT = Layout("egm_status", KIND_EGM_STATUS, 1, EGM_STATUS, "droid_egm_status")
