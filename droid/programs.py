"""Every DROID program: console-script name -> module with ``main(argv=None) -> int``.

The launcher starts programs as ``python -m MODULE`` with this interpreter, so a
cell runs the same whether or not the console scripts are on PATH; the console
scripts in pyproject.toml point at the same modules.
"""
from __future__ import annotations

# name -> (module, where it runs)
PROGRAMS: dict[str, str] = {
    # Brain
    "droid-cell": "droid.brain.launcher",
    "droid-heartbeat": "droid.brain.heartbeat",
    "droid-names": "droid.brain.names",
    "droid-remote": "droid.brain.remote",
    "droid-cheader": "droid.brain.cheader",
    "droid-keys": "droid.brain.keys",
    "droid-kin": "droid.kinematics.cli",
    # subunit agents
    "droid-agent": "droid.subunits.agent",
    "droid-reis-agent": "droid.subunits.reis.agent",
    "droid-gmf1-agent": "droid.subunits.gmf1.agent",
    "droid-gmf1-serial": "droid.subunits.gmf1.serial_prog",
    "droid-gmf1-encoder": "droid.subunits.gmf1.encoder_prog",
    "droid-planner": "droid.subunits.reis.planner",
    "droid-servo": "droid.subunits.reis.servo_prog",
    "droid-servo-agent": "droid.subunits.reis.servo_agent",
    "droid-watchdog": "droid.subunits.reis.watchdog_prog",
    "droid-mvs": "droid.subunits.mvs.sensor",
    "droid-joystick": "droid.subunits.joystick.prog",
    "droid-ft": "droid.subunits.ft.prog",
    "droid-egm": "droid.subunits.abb.egm_prog",
    "droid-mvs-board": "droid.sim.mvs.dsp",
    # tasks
    "droid-snoop": "droid.tasks.snoop",
    "droid-move": "droid.tasks.move",
    "droid-home": "droid.tasks.home",
    "droid-jog": "droid.tasks.jog",
    "droid-seamtrack": "droid.tasks.seamtrack",
    "droid-experiment": "droid.experiments.cli",
    # the world
    "droid-sim": "droid.sim.world",
    "droid-calibrate": "droid.sim.reis.calibrate",
    # tools
    "droid-fault": "droid.faults.cli",
    # observers (docs/observe.md)
    "droid-record": "droid.observe.record",
    "droid-replay": "droid.observe.replay",
    "droid-web": "droid.observe.web",
    "droid-foxglove": "droid.observe.foxglove",  # needs the optional extra droid[foxglove]
}
