"""The six-axis force/torque sensor (ATI Net F/T over RDT) as a device package (thesis §7.3; docs/design.md §11).

Defines class ``ft6`` (its layout ``ft6_status`` in :mod:`droid.brain.db.layouts`), its program
``droid-ft`` (served by the generic ``droid-agent``; its read rate is its URL's ``rate_hz``),
its ``netft://`` driver, its twin ``netft`` and its lockstep builder (:func:`droid.sim.ft.lockstep.build`).
"""
from __future__ import annotations

from droid.brain.cell.classes import SubunitClass
from droid.brain.db.layouts import FT6_COMMAND_LAYOUT, FT6_CTRL_COMMAND_LAYOUT, FT6_STATUS_LAYOUT
from droid.brain.cell.registry import DevicePackage, Driver, Program, Twin

#: URL scheme -> driver class (droid.subunits.ft.rdt.DRIVERS holds the same classes)
DRIVER_CLASSES = {"netft": "droid.subunits.ft.rdt:NetFtDevice"}

FT6 = SubunitClass(
    name="ft6",
    description="six-axis force/torque sensor on Ethernet (ATI Net F/T, RDT; thesis §7.3)",
    brain={"status": FT6_STATUS_LAYOUT, "command": FT6_COMMAND_LAYOUT},
    local={"ctrl_status": FT6_STATUS_LAYOUT, "ctrl_command": FT6_CTRL_COMMAND_LAYOUT},
    copy_fields=("force_N", "torque_Nm", "force_tool_N", "torque_tool_Nm", "sample_ns", "sample_age_ms",
                 "rdt_seq", "ft_seq", "status_word", "valid", "saturated", "biased", "dropped",
                 "out_of_order", "bad_datagrams", "records", "fault"),
    snoop_fields=("force_N", "torque_Nm", "force_tool_N", "torque_tool_Nm", "sample_age_ms", "valid",
                  "saturated", "biased", "rdt_seq", "dropped", "out_of_order", "bad_datagrams", "fault"),
    drivers=DRIVER_CLASSES,
    command_map={"guard_force_n": "guard_force_n", "bias_id": "bias_id", "sent": "sent", "cmd_id": "cmd_id"},
)

PACKAGE = DevicePackage(
    name="ft",
    description="ATI Net F/T force/torque sensor over RDT (UDP) and its HTTP calibration (docs/ft.md)",
    classes=(FT6,),
    # SCHED_FIFO 53: droid-ft holds the over-force guard of the arm it sits on (FAULT_FORCE),
    # so it runs above the agents (51) and the world (52), below the servo (60).  On the normal
    # scheduler it went 70-100 ms without a record while the pressing cell held both cores.
    programs=(Program("droid-ft", "droid.subunits.ft.prog", sched="fifo", priority=53,
                      description="reads the sensor's RDT stream at its URL's rate_hz into its Status",
                      cpu_pct=4.0, rss_mb=44),),
    drivers=(Driver("ft", tuple(DRIVER_CLASSES), "droid.subunits.ft.rdt:open_ft",
                    "netft://HOST[:PORT][?rate_hz=HZ&http_port=N&bias=0|1]"),),
    twins=(Twin("netft", "droid.sim.ft.netft:make_netft", serves=("ft6",), cpu_pct=1.0),),
    lockstep="droid.sim.ft.lockstep:build",
)
