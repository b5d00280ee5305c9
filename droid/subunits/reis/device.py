"""The Reis motion controller as a device package (thesis §4.1; docs/design.md §11).

Serves class ``arm6r`` (defined by the Brain: the Reis and the GMF1 are both 6R arms
to it).  Its programs, in the thesis's start order on a real arm1 (watchdog, servo,
servo agent, agent, planner), the VME driver, the ``reis_vme`` twin and the lockstep
builder (:func:`droid.sim.reis.cell.build`: the whole arm, :class:`~droid.sim.reis.cell.LockstepArm`).  The servo's 500 Hz is written here once (:data:`SERVO_HZ`).
"""
from __future__ import annotations

from droid.brain.cell.device import HEARTBEAT_HZ
from droid.brain.cell.registry import DevicePackage, Driver, Program, Twin

#: The servo loop's rate [Hz] (thesis §4.1.5): droid-servo, the servo parameters, the
#: lockstep cell and the world's Reis read it from here.
SERVO_HZ = 500.0
#: The watchdog's kick rate [Hz] (§2.3).
WATCHDOG_HZ = 50.0

# Alike in shape only to the GMF1 package's declaration: one DevicePackage each, its own programs.
PACKAGE = DevicePackage(
    name="reis",
    description="Reis Robotstar V15 motion controller on VME cards (thesis §4.1)",
    serves=("arm6r",),
    programs=(
        Program("droid-watchdog", "droid.subunits.reis.watchdog_prog", rate_hz=WATCHDOG_HZ, sched="fifo",
                priority=55, cpu_pct=1.5, rss_mb=44),
        Program("droid-servo", "droid.subunits.reis.servo_prog", rate_hz=SERVO_HZ, sched="fifo", priority=60,
                cpu_pct=12.0, rss_mb=48),
        Program("droid-servo-agent", "droid.subunits.reis.servo_agent", rate_hz=HEARTBEAT_HZ, sched="fifo",
                priority=54, cpu_pct=4.5, rss_mb=47),
        Program("droid-reis-agent", "droid.subunits.reis.agent", sched="fifo", priority=51, cpu_pct=3.5, rss_mb=42),
        Program("droid-planner", "droid.arm.planner", sched="fifo", priority=51, cpu_pct=2.5, rss_mb=47),
        Program("droid-calibrate", "droid.sim.reis.calibrate", role="tool"),
    ),
    drivers=(Driver("vme", ("shm", "mem"), "droid.subunits.reis.vme:open_vme",
                    "shm://NAME or mem:///PATH?offset=0xADDR"),),
    twins=(Twin("reis_vme", "droid.sim.reis.world:make_reis", serves=("arm6r",), cpu_pct=2.0),
           Twin("contact", "droid.sim.contact_device:make_contact", cpu_pct=0.5)),  # a workpiece pushing on its tool
    lockstep="droid.sim.reis.cell:build",
    lockstep_models=(("fast", "droid.sim.reis.fast_arm:FastArm"),),  # calibrated against its servo and plant
)
