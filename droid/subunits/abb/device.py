"""An ABB arm on Externally Guided Motion as a device package (issue 26, thesis §7.3; docs/design.md §11).

Serves class ``arm6r`` like the Reis and the GMF1: an ABB subunit runs the Reis package's
``droid-reis-agent`` and ``droid-planner`` and this package's ``droid-egm`` in the servo
agent's place (docs/abb.md).  Its twin ``abb_egm`` is the controller's side of EGM.  The
``egm`` key's ``udp://HOST:PORT`` is bound by droid-egm itself (no driver to open); droid-fault's
proxy may interpose it (``proxy_endpoints``).  Its
lockstep builder, :func:`droid.sim.abb.lockstep.build`, puts the subunit's stations and the twin
(:class:`~droid.sim.abb.lockstep.LockstepAbbArm`) on a lockstep scheduler from a cell file.
"""
from __future__ import annotations

from droid.brain.cell.registry import DevicePackage, Program, Twin

PACKAGE = DevicePackage(
    name="abb",
    description="ABB IRB arm over EGM (UDP, protobuf) with its controller closing the joint loops",
    serves=("arm6r",),
    # in the servo agent's place: answers the controller every 4 ms
    programs=(Program("droid-egm", "droid.subunits.abb.egm_prog", sched="fifo", priority=54, cpu_pct=8.0,
                      rss_mb=45),),
    twins=(Twin("abb_egm", "droid.sim.abb.controller:make_abb_egm", serves=("arm6r",), cpu_pct=3.0),),
    lockstep="droid.sim.abb.lockstep:build",
    proxy_endpoints="droid.subunits.abb.config:proxy_endpoints",  # its EGM address, for droid-fault
)
