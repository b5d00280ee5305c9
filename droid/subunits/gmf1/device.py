"""The GM Fanuc S400 (GMF1) motion controller as a device package (thesis §4.2; docs/design.md §11).

Serves class ``arm6r`` like the Reis: the Brain sees one kind of arm.  Its programs,
the encoder-card driver (the KAREL line uses the Brain's ``serial`` driver), the
``karel_s400`` twin and the lockstep builder (:func:`droid.sim.gmf1.lockstep.build`).
"""
from __future__ import annotations

from droid.brain.cell.registry import DevicePackage, Driver, Program, Twin

#: The encoder program's rate [Hz] (§4.2.5).
ENCODER_HZ = 120.0

# Alike in shape only to the Reis package's declaration: one DevicePackage each, its own programs.
PACKAGE = DevicePackage(
    name="gmf1",
    description="GM Fanuc S400 over its KAREL serial server and CIO-QUAD04 encoder cards (thesis §4.2)",
    serves=("arm6r",),
    programs=(
        Program("droid-gmf1-agent", "droid.subunits.gmf1.agent", sched="nice", cpu_pct=3.5, rss_mb=42),  # the KAREL
        # controller interpolates on its own: ticks late by a few ms reach it at <= 6 Hz anyway
        Program("droid-gmf1-serial", "droid.subunits.gmf1.serial_prog", sched="nice", cpu_pct=2.5, rss_mb=44),
        Program("droid-gmf1-encoder", "droid.subunits.gmf1.encoder_prog", rate_hz=ENCODER_HZ, sched="nice",
                cpu_pct=2.5, rss_mb=46),
    ),
    drivers=(Driver("encoder_card", ("shm", "mem"), "droid.subunits.gmf1.quad04:open_card",
                    "shm://NAME or mem:///PATH?offset=0xADDR"),),
    twins=(Twin("karel_s400", "droid.sim.gmf1.karel:make_karel", serves=("arm6r",), cpu_pct=2.5),),
    lockstep="droid.sim.gmf1.lockstep:build",
    lockstep_models=(("holder", "droid.sim.gmf1.holder:Gmf1Holder"),),  # a trial's workpiece holder
)
