"""The Brain's device package (docs/design.md §11): the Brain's programs, the tools, the generic
subunit agent, the serial-port driver, the serial-cable twin and the two classes the Brain
itself defines -- ``arm6r`` (thesis Tables 3.1-3.2, 4.2-4.3) and ``line_laser`` (Table 3.3),
interfaces that several device packages serve (the Reis and GMF1 program sets both serve
``arm6r``; the MVS serves ``line_laser``).  Registered first in
:data:`droid.brain.cell.registry.BUILTIN_PACKAGES`.

Rates written here once: the heartbeat's 60 Hz (§3.2) -- the default of a cell's
``heartbeat_hz`` and the command rate of everything that runs on the heartbeat's tick.
"""
from __future__ import annotations

from droid.brain.cell.classes import ARM6R, LINE_LASER
from droid.brain.cell.registry import DevicePackage, Driver, Program, Twin

#: The heartbeat's rate [Hz] (thesis §3.2): the default ``[cell] heartbeat_hz``.
HEARTBEAT_HZ = 60.0

#: pyserial's URL handlers (serial/urlhandler/protocol_*.py) and "" for a device path.
SERIAL_SCHEMES = ("", "loop", "socket", "rfc2217", "spy", "alt", "hwgrep", "cp2110")

PACKAGE = DevicePackage(
    name="brain",
    description="the Brain (thesis §3.2): name space, heartbeat, remotes, launcher; tasks and tools",
    classes=(ARM6R, LINE_LASER),
    generic=True,  # droid-agent serves a subunit of any class
    programs=(
        # the Brain (started by droid-cell up for every cell)
        Program("droid-names", "droid.brain.runtime.names", start=0, role="brain", cpu_pct=0.5, rss_mb=40),
        Program("droid-heartbeat", "droid.brain.runtime.heartbeat", rate_hz=HEARTBEAT_HZ, sched="fifo", priority=50,
                role="brain", cpu_pct=2.0, rss_mb=45),
        # several ([brain] remotes = "one"): a further subunit 0.4-0.6 % (docs/benchmarks.md "Scale")
        Program("droid-remote", "droid.brain.runtime.remote", sched="fifo", priority=50, role="brain",
                cpu_pct=3.5, rss_mb=47, several=True, cpu_pct_each=0.6),
        Program("droid-sim", "droid.sim.world", rate_hz=1000.0, sched="fifo", priority=52, start=0,
                role="brain", description="the world: every twin of the cell",
                cpu_pct=13.0, rss_mb=100),  # its loop (1 kHz steps, woken at 500 Hz here); + each Twin.cpu_pct
        # the generic subunit server (any class: copies the command in, replies with the status)
        # ([cell] share: a further subunit 0.45 %, docs/benchmarks.md "Scale")
        Program("droid-agent", "droid.subunits.agent", sched="fifo", priority=51, cpu_pct=3.0, rss_mb=42,
                several=True, cpu_pct_each=0.5),
        # tools and tasks (run by hand)
        Program("droid-cell", "droid.brain.runtime.launcher", role="tool"),
        Program("droid-cheader", "droid.brain.runtime.cheader", role="tool"),
        Program("droid-keys", "droid.brain.runtime.keys", role="tool"),
        Program("droid-kin", "droid.kinematics.cli", role="tool"),
        # the collision guard between the arms (issue 41; docs/guard.md): droid-cell up starts it on the
        # Brain's host where the cell declares [guard]; SCHED_FIFO as the remotes: a guard that misses
        # its ticks goes stale and stops every arm (droid.guard.gate)
        Program("droid-guard", "droid.guard.cli", rate_hz=HEARTBEAT_HZ, sched="fifo", priority=50, role="brain",
                description="the cell's collision guard, where it declares [guard]", cpu_pct=10.0,
                rss_mb=50),  # cpu_pct: bench_rt_budget, session 26 (8.0-10.6 % live; 2.1 % in lockstep)
        Program("droid-snoop", "droid.tasks.snoop", role="tool"),
        Program("droid-move", "droid.tasks.move", role="tool"),
        Program("droid-home", "droid.tasks.home", role="tool"),
        Program("droid-jog", "droid.tasks.jog", role="tool"),
        Program("droid-seamtrack", "droid.tasks.seamtrack", rate_hz=HEARTBEAT_HZ / 2, sched="fifo", priority=49,
                role="tool"),  # below the remotes and agents; at nice -10 it lost ticks beside busy work (issue 40)
        Program("droid-contact", "droid.tasks.contact.prog", rate_hz=HEARTBEAT_HZ / 2, sched="fifo", priority=49,
                role="tool"),
        Program("droid-experiment", "droid.experiments.cli", role="tool"),
        Program("droid-fault", "droid.faults.cli", sched="fifo", priority=50, role="tool"),
        Program("droid-record", "droid.observe.record", sched="fifo", priority=10, role="tool"),
        Program("droid-replay", "droid.observe.replay", role="tool"),
        Program("droid-web", "droid.observe.web", role="tool"),
        Program("droid-foxglove", "droid.observe.foxglove", role="tool",
                description="needs the optional extra droid[foxglove]"),
        Program("droid-ros2", "droid.ros2.node", role="tool",
                description="needs the optional extra droid[ros2]"),
    ),
    drivers=(
        Driver("serial", SERIAL_SCHEMES, "droid.brain.plumbing.serial_port:serial_opener",
               "a device path (/dev/ttyS0) or a pyserial URL (socket://HOST:PORT, loop://, ...)"),
    ),
    twins=(Twin("serial_cable", "droid.sim.serial_cable:serial_cable", cpu_pct=1.0),),
)
