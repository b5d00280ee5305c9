"""The MVS line-laser seam sensor as a device package (thesis §2.5, §5.3-5.4; docs/design.md §11).

Serves class ``line_laser`` (Table 3.3, defined by the Brain).  Its program, the DSP
board driver (its serial line uses the Brain's ``serial`` driver), its twins -- the
camera and DSP board, the tool-tip measuring sensor, and the fixed arm the sensor
rigs use -- the lockstep builder (:func:`droid.sim.mvs.lockstep.build`) and a seam-tracking
trial's truth sensors on the layout's ``sensor`` (its ``lead`` lockstep model,
:class:`droid.sim.mvs.trial_sensors.LeadSensor`, with the tool-tip sensor beside it).
"""
from __future__ import annotations

from droid.brain.cell.registry import DevicePackage, Driver, Program, Twin
from droid.subunits.mvs.wire import FRAME_RATE_HZ  # the video frame rate [Hz] (§2.5): a line a frame

PACKAGE = DevicePackage(
    name="mvs",
    description="MVS line-laser seam sensor: DSP frames -> x, y, roll on a serial line (thesis §5.4)",
    serves=("line_laser", "arm6r"),  # arm6r: its fixed_arm twin stands in for an arm
    programs=(
        Program("droid-mvs", "droid.subunits.mvs.sensor", rate_hz=FRAME_RATE_HZ, sched="nice",  # lines carry their capture time
                cpu_pct=2.0, rss_mb=41),
        Program("droid-mvs-board", "droid.sim.mvs.dsp", role="tool",
                description="a stand-alone DSP board twin for the sensor alone"),
    ),
    drivers=(Driver("dsp", ("shm", "inproc"), "droid.subunits.mvs.dsp:open_dsp", "shm://NAME or inproc://NAME"),),
    twins=(
        Twin("mvs_camera", "droid.sim.mvs.devices:mvs_camera", serves=("line_laser",), cpu_pct=1.5),
        Twin("tool_sensor", "droid.sim.mvs.devices:tool_sensor", serves=("line_laser",), cpu_pct=2.5),
        Twin("fixed_arm", "droid.sim.mvs.arm:fixed_arm", serves=("arm6r",), cpu_pct=0.5),
    ),
    lockstep="droid.sim.mvs.lockstep:build",
    lockstep_models=(("lead", "droid.sim.mvs.trial_sensors:LeadSensor"),),  # a trial's lead and tool-tip sensors
)
