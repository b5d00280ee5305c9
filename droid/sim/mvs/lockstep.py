"""The MVS chain on a lockstep Scheduler: camera twin -> sensor core -> paced line -> the Brain's link core -> Status.

The same devices as droid-sim's (:mod:`droid.sim.mvs.devices`) and the same
cores as droid-mvs and droid-remote, on virtual time (thesis §2.5, §5.4, §6.1).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any, Mapping

from droid.brain.layouts import SENSOR_STATUS_LAYOUT
from droid.brain.sensor_line import DEFAULT_BAUD, format_line
from droid.brain.sensor_link import SensorStatusCore
from droid.brain.shmdb import MemoryDatabase
from droid.brain.wire import LIVENESS_TICKS
from droid.cli import BadInput
from droid.sim.device_options import DeviceOptions
from droid.sim.mvs.devices import IdealSensorCore, MvsCameraDevice, ToolSensorDevice, build_camera, tool_parts
from droid.sim.serial_cable import PacedPipe
from droid.subunits.mvs.calibration import MvsCalibration


_LOCKSTEP_IDS = itertools.count(1)


@dataclass
class SensorChain:
    """The Brain side of one serial-linked sensor in lockstep."""

    pipe: PacedPipe  # the cable, in memory on virtual time
    link: SensorStatusCore  # what droid-remote NAME runs each tick
    status: MemoryDatabase  # the sensor's Status record (Table 3.3)


@dataclass
class MvsLockstep:
    """What :func:`mvs_lockstep` put on the scheduler (its cores, for inspection)."""

    camera: MvsCameraDevice
    sensor: Any  # droid.subunits.mvs.sensor.SensorCore
    board: Any  # the sensor program's DSP board reader (inproc)
    mvs: SensorChain
    tool: ToolSensorDevice | None = None
    tool_chain: SensorChain | None = None
    retrace_timeouts: int = 0

    def close(self) -> None:
        self.board.close()
        self.camera.close()


def mvs_lockstep(scheduler, devices: Mapping[str, Any], camera: dict[str, Any],
                 tool: dict[str, Any] | None = None, *, seed: int = 0, stale_ticks: int = LIVENESS_TICKS,
                 baud: int = DEFAULT_BAUD, sensor_calibration: dict | None = None,
                 retrace_timeout_s: float = 0.1, ideal_sensor: bool = False,
                 name: str = "lockstep") -> MvsLockstep:
    """Put the MVS chain (and the tool-tip sensor) on a lockstep :class:`~droid.sim.lockstep.Scheduler`.

    ``devices`` maps names to world devices (the arm twins, with
    ``wcp_global()``); their own stepping is the caller's (the world task).
    ``camera`` and ``tool`` are option tables as in the cell file's
    ``[world.devices.mvs_camera]`` / ``[world.devices.tool_sensor]`` without
    ``dsp`` / ``serial`` / ``baud``.  Tasks, at 60 Hz from t = 0:

    * ``<name>.mvs_camera`` (ORDER_WORLD): render the frame into an
      ``inproc://`` board;
    * ``<name>.tool_sensor`` (ORDER_WORLD): measure, queue the line;
    * ``<name>.mvs_sensor`` (ORDER_DEVICE): droid-mvs's core -- take the frame,
      extract, queue the line (``invalid`` after ``retrace_timeout_s``
      without a frame, as droid-mvs does);
    * on every heartbeat tick (ORDER_HEARTBEAT) ``<name>.mvs_link`` /
      ``<name>.tool_link``: droid-remote's core -- read what the paced line
      delivered by now, write the Status record (a MemoryDatabase).

    The lines travel through :class:`PacedPipe` at ``baud``, so a reading
    reaches the Status about one tick after its frame, as in the real-time
    cell.  Call ``close()`` at the end (it releases the inproc board).

    ``ideal_sensor=True`` skips the camera and the feature extraction (most of
    the cost: ~1 ms a frame): the lead sensor's line is the exact geometry
    (:func:`~droid.sim.mvs.tool_sensor.measure` at S, as the tool-tip sensor
    reports it), ``invalid`` outside the sensor calibration's field of view.
    No pixels, no noise; use it where only the geometry matters.
    """
    from droid.sim.lockstep import ORDER_DEVICE, ORDER_WORLD
    from droid.brain.registry import open_url
    from droid.subunits.mvs.sensor import SensorCore

    uid = next(_LOCKSTEP_IDS)
    world = SimpleNamespace(devices=dict(devices), seed=seed, cell=None)
    cam_opts = dict(camera)
    if "dsp" in cam_opts:
        raise BadInput("mvs_lockstep: camera option 'dsp' is chosen by the lockstep runner")
    url = f"inproc://{name}.{uid}.mvs.dsp"
    cam = build_camera(DeviceOptions(world, "mvs_camera", cam_opts), url)
    board = open_url(url, "dsp")
    calib = MvsCalibration.from_table(sensor_calibration or {}, source="mvs_lockstep sensor_calibration")
    sensor = SensorCore(calib)

    def chain(what: str) -> SensorChain:
        return SensorChain(PacedPipe(baud), SensorStatusCore(stale_ticks),
                           MemoryDatabase(f"/{name}.{what}.status", SENSOR_STATUS_LAYOUT))

    run = MvsLockstep(cam, sensor, board, chain("mvs"))
    if tool is not None:
        opts = DeviceOptions(world, "tool_sensor", dict(tool))
        mount, core, rate = tool_parts(opts)
        opts.done()
        run.tool = ToolSensorDevice("tool_sensor", mount, core, output=None, rate_hz=rate)
        run.tool_chain = chain("tool")
    timeout_ns = int(round(retrace_timeout_s * 1e9))
    last_line_ns = [0]

    def camera_task(t_ns: int) -> None:
        cam.frame(t_ns)

    ideal = IdealSensorCore(cam.twin.camera.workpiece, calib) if ideal_sensor else None

    def ideal_task(t_ns: int) -> None:
        sensor.frames += 1
        run.mvs.pipe.write(ideal.step(cam.mount.T_W()), t_ns)

    def sensor_task(t_ns: int) -> None:
        got = board.wait_frame(0)
        if got is not None:
            line = sensor.step(got.rows)
        elif t_ns - last_line_ns[0] >= timeout_ns:
            run.retrace_timeouts += 1
            line = format_line(None)
        else:
            return
        last_line_ns[0] = t_ns
        run.mvs.pipe.write(line, t_ns)

    def link_task(ch: SensorChain):
        def on_tick(tick: int) -> None:
            t_ns = scheduler.t_ns
            ch.status.update(**ch.link.on_tick(tick, ch.pipe.read(t_ns), t_ns))
        return on_tick

    if ideal is None:
        scheduler.every(cam.clock.rate_hz, camera_task, f"{name}.mvs_camera", order=ORDER_WORLD)
        scheduler.every(cam.clock.rate_hz, sensor_task, f"{name}.mvs_sensor", order=ORDER_DEVICE)
    else:
        scheduler.every(cam.clock.rate_hz, ideal_task, f"{name}.mvs_sensor", order=ORDER_DEVICE)
    scheduler.on_tick(link_task(run.mvs), f"{name}.mvs_link")
    if run.tool is not None:
        tool_dev, tool_chain = run.tool, run.tool_chain
        scheduler.every(tool_dev.clock.rate_hz, lambda t_ns: tool_chain.pipe.write(tool_dev.line(t_ns), t_ns),
                        f"{name}.tool_sensor", order=ORDER_WORLD)
        scheduler.on_tick(link_task(tool_chain), f"{name}.tool_link")
    return run
