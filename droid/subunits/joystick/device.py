"""The analog joystick as a device package (thesis §2.6 Figure 2.10, §3.4; docs/design.md §11).

Defines class ``joystick`` (its layout ``joystick_status``), its program
``droid-joystick`` (the generic ``droid-agent`` serves it), its drivers ``js://`` and
``evdev://``, its twin, a Linux joystick device on a pty, and its lockstep builder
(:mod:`droid.sim.joystick.lockstep`: the twin's bytes read by droid-joystick's station).
"""
from __future__ import annotations

from droid.brain.cell.classes import SubunitClass
from droid.brain.db.layouts import JOYSTICK_STATUS_LAYOUT
from droid.brain.cell.registry import DevicePackage, Driver, Program, Twin

#: URL scheme -> driver class (droid.subunits.joystick.driver.DRIVERS holds the same classes)
DRIVER_CLASSES = {"js": "droid.subunits.joystick.driver:JsDevice",
                  "evdev": "droid.subunits.joystick.driver:EvdevDevice"}

JOYSTICK = SubunitClass(
    name="joystick",
    description="analog joystick: axes and buttons (thesis §2.6 Figure 2.10, §3.4)",
    brain={"status": JOYSTICK_STATUS_LAYOUT},
    local={"ctrl_status": JOYSTICK_STATUS_LAYOUT},
    copy_fields=("axes", "buttons", "valid", "events", "fault", "n_axes", "n_buttons"),
    snoop_fields=("axes", "buttons", "valid", "events", "n_axes", "n_buttons", "fault"),
    drivers=DRIVER_CLASSES,
)

PACKAGE = DevicePackage(
    name="joystick",
    description="a Linux joystick device read into its subunit's Status (docs/joystick.md)",
    classes=(JOYSTICK,),
    programs=(Program("droid-joystick", "droid.subunits.joystick.prog", rate_hz=100.0, cpu_pct=2.0,
                      rss_mb=37, several=True,
                      cpu_pct_each=0.1),),  # [cell] share: 33 joysticks took 4.6 % (docs/benchmarks.md "Scale")
    drivers=(Driver("joystick", tuple(DRIVER_CLASSES), "droid.subunits.joystick.driver:open_joystick",
                    "js:///dev/input/jsN or evdev:///dev/input/eventN[?min=LO&max=HI]"),),
    twins=(Twin("joystick", "droid.sim.joystick.device:make_joystick", serves=("joystick",), cpu_pct=0.2),),
    lockstep="droid.sim.joystick.lockstep:build",
)
