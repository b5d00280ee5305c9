"""The MVS chain on a lockstep Scheduler: camera twin -> sensor station -> paced line -> the Brain's link -> Status.

The same devices as droid-sim's (:mod:`droid.sim.mvs.devices`), droid-mvs's station
(:class:`~droid.subunits.mvs.station.MvsStation`) and droid-remote's core, on virtual
time (thesis §2.5, §5.4, §6.1).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any, Mapping

from droid.brain.db.layouts import SENSOR_STATUS_LAYOUT
from droid.brain.plumbing.sensor_line import DEFAULT_BAUD
from droid.brain.runtime.sensor_link import SensorStatusCore
from droid.brain.db.shmdb import MemoryDatabase
from droid.brain.plumbing.wire import LIVENESS_TICKS
from droid.cli import BadInput
from droid.sim.device_options import DeviceOptions
from droid.sim.mvs.devices import IdealSensorCore, MvsCameraDevice, ToolSensorDevice, build_camera, tool_parts
from droid.sim.serial_cable import PacedPipe
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.station import MvsStation, SensorCore
from droid.sim.lockstep_build import LockstepSubunit, builds


_LOCKSTEP_IDS = itertools.count(1)


@dataclass
class SensorChain:
    """The Brain side of one serial-linked sensor in lockstep."""

    pipe: PacedPipe  # the cable, in memory on virtual time
    link: SensorStatusCore  # what droid-remote NAME runs each tick
    status: MemoryDatabase  # the sensor's Status record (Table 3.3)


class CablePort:
    """The lockstep cable as the sensor station's port: always open; a line that does not fit
    is dropped (an overrun, as a write that times out on droid-mvs's port)."""

    is_open = True
    last_error = ""

    def __init__(self, pipe: PacedPipe, clock) -> None:
        self.pipe = pipe
        self.clock = clock  # () -> the virtual time [ns]

    def open(self) -> bool:
        return True

    def write(self, data: bytes) -> bool:
        return self.pipe.write(data, self.clock())


@dataclass
class MvsLockstep:
    """What :func:`mvs_lockstep` put on the scheduler (its cores, for inspection)."""

    camera: MvsCameraDevice
    sensor: SensorCore
    board: Any  # the sensor program's DSP board reader (inproc)
    mvs: SensorChain
    station: MvsStation | None = None  # droid-mvs's cycle (None with ideal_sensor)
    tool: ToolSensorDevice | None = None
    tool_chain: SensorChain | None = None

    @property
    def retrace_timeouts(self) -> int:
        """'invalid' lines the station sent for frames that did not come in time."""
        return self.station.timeouts if self.station is not None else 0

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
    * ``<name>.mvs_sensor`` (ORDER_DEVICE): droid-mvs's station -- take the frame,
      extract, queue the line; a frame slot without a frame is one frame period
      waited (``invalid`` once ``retrace_timeout_s`` of them add up, the station's
      timeout rule, as in droid-mvs);
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
    from droid.brain.cell.registry import open_url

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
    run = MvsLockstep(cam, sensor, board, _sensor_chain(name, "mvs", baud, stale_ticks))
    if tool is not None:
        run.tool, run.tool_chain = _tool_sensor(world, tool), _sensor_chain(name, "tool", baud, stale_ticks)
    if not ideal_sensor:  # the retrace timeout in the camera's frame periods
        run.station = MvsStation(sensor, CablePort(run.mvs.pipe, lambda: scheduler.t_ns),
                                 timeout_frames=retrace_timeout_s * cam.clock.rate_hz)
    ideal = IdealSensorCore(cam.twin.camera.workpiece, calib) if ideal_sensor else None
    _schedule(scheduler, run, ideal, name)
    return run


def _sensor_chain(name: str, what: str, baud: int, stale_ticks: int) -> SensorChain:
    """A sensor's paced line, droid-remote's core for it and its Status record."""
    return SensorChain(PacedPipe(baud), SensorStatusCore(stale_ticks),
                       MemoryDatabase(f"/{name}.{what}.status", SENSOR_STATUS_LAYOUT))


def _tool_sensor(world, tool: dict[str, Any]) -> ToolSensorDevice:
    """The tool-tip sensor from its option table (no serial output: the lockstep line takes it)."""
    opts = DeviceOptions(world, "tool_sensor", dict(tool))
    mount, core, rate = tool_parts(opts)
    opts.done()
    return ToolSensorDevice("tool_sensor", mount, core, output=None, rate_hz=rate)


def _schedule(scheduler, run: MvsLockstep, ideal: IdealSensorCore | None, name: str) -> None:
    """The chain's tasks on the scheduler (mvs_lockstep's docstring): camera and sensor station
    (or the ideal sensor) at the camera's rate, the tool-tip sensor at its own, the links on
    every heartbeat tick."""
    from droid.sim.lockstep import ORDER_DEVICE, ORDER_WORLD

    cam, sensor, board = run.camera, run.sensor, run.board
    waited = [0.0]  # frame periods since the previous slot: none at the first (the station starts there)

    def camera_task(t_ns: int) -> None:
        cam.frame(t_ns)

    def ideal_task(t_ns: int) -> None:
        sensor.frames += 1
        run.mvs.pipe.write(ideal.step(cam.mount.T_W()), t_ns)

    def sensor_task(t_ns: int) -> None:
        got = board.wait_frame(0)
        if got is not None:
            run.station.on_frame(got.rows, missed=got.missed)
        else:
            run.station.on_wait(waited[0])
        waited[0] = 1.0

    if ideal is None:
        scheduler.every(cam.clock.rate_hz, camera_task, f"{name}.mvs_camera", order=ORDER_WORLD)
        scheduler.every(cam.clock.rate_hz, sensor_task, f"{name}.mvs_sensor", order=ORDER_DEVICE)
    else:
        scheduler.every(cam.clock.rate_hz, ideal_task, f"{name}.mvs_sensor", order=ORDER_DEVICE)
    scheduler.on_tick(_link_task(scheduler, run.mvs), f"{name}.mvs_link")
    if run.tool is not None:
        _schedule_tool(scheduler, run.tool, run.tool_chain, name)


def _link_task(scheduler, ch: SensorChain):
    """droid-remote's tick for a serial-linked sensor: what the paced line delivered by now -> Status."""
    def on_tick(tick: int) -> None:
        t_ns = scheduler.t_ns
        ch.status.update(**ch.link.on_tick(tick, ch.pipe.read(t_ns), t_ns))
    return on_tick


def _schedule_tool(scheduler, tool_dev: ToolSensorDevice, tool_chain: SensorChain, name: str) -> None:
    """The tool-tip sensor's line at its rate (ORDER_WORLD) and its link on every tick."""
    from droid.sim.lockstep import ORDER_WORLD

    scheduler.every(tool_dev.clock.rate_hz, lambda t_ns: tool_chain.pipe.write(tool_dev.line(t_ns), t_ns),
                    f"{name}.tool_sensor", order=ORDER_WORLD)
    scheduler.on_tick(_link_task(scheduler, tool_chain), f"{name}.tool_link")


@dataclass
class ToolLockstep:
    """A tool-tip measuring sensor alone on the scheduler (a ``line_laser`` subunit with no program)."""

    tool: ToolSensorDevice
    tool_chain: SensorChain

    def close(self) -> None:
        pass


def _matching(ctx, typ: str, key: str, value) -> tuple[str, dict] | None:
    """The first ``[world.devices.*]`` table of ``typ`` whose ``key`` is ``value`` (None: none)."""
    return next(((n, o) for n, o in ctx.world_devices(typ).items() if value is not None and o.get(key) == value), None)


@builds("droid-mvs")
def build(ctx, sub) -> LockstepSubunit:
    """The lockstep slot of the MVS package (droid.sim.lockstep_build) for a ``line_laser`` subunit:
    with ``droid-mvs``, :func:`mvs_lockstep` of the ``mvs_camera`` world device writing its board
    (its ``dsp`` is the subunit's) looking from and at the arms of ``ctx.twins``; without, the
    ``tool_sensor`` device writing its line (its ``serial`` is the subunit's).  The line's baud,
    the sensor's calibration (``[subunits.X.calibration]``) and the cell's ``stale_ticks`` are
    the subunit's; BadInput (one line) when the world has no such device."""
    from droid.brain.plumbing.sensor_line import DEFAULT_BAUD as baud_default

    world = SimpleNamespace(devices=ctx.twins, seed=ctx.seed, cell=None)
    baud = int(sub.options.get("baud", baud_default))
    if "droid-mvs" in sub.programs:
        found = _matching(ctx, "mvs_camera", "dsp", sub.options.get("dsp"))
        if found is None:
            raise BadInput(f"{ctx.where(sub)} has no camera: no [world.devices.*] of type mvs_camera writes "
                           f"its dsp {sub.options.get('dsp')!r}")
        cam = {k: v for k, v in found[1].items() if k != "dsp"}
        run = mvs_lockstep(ctx.sched, ctx.twins, cam, seed=ctx.seed, stale_ticks=ctx.cell.stale_ticks, baud=baud,
                           sensor_calibration=sub.options.get("calibration"), name=sub.name)
        stations = {"droid-mvs": [f"{sub.name}.mvs_sensor", f"{sub.name}.mvs_link"]}
        return LockstepSubunit(sub.name, sub.cls, run.mvs.status, None, stations, None, run)
    found = _matching(ctx, "tool_sensor", "serial", sub.options.get("serial"))
    if found is None:
        raise BadInput(f"{ctx.where(sub)} runs no droid-mvs and no [world.devices.*] of type tool_sensor "
                       f"writes its serial {sub.options.get('serial')!r}: nothing writes its line")
    tool = {k: v for k, v in found[1].items() if k not in ("serial", "baud")}
    tool_run = ToolLockstep(_tool_sensor(world, tool), _sensor_chain(sub.name, "tool", baud, ctx.cell.stale_ticks))
    _schedule_tool(ctx.sched, tool_run.tool, tool_run.tool_chain, sub.name)
    return LockstepSubunit(sub.name, sub.cls, tool_run.tool_chain.status, None, {}, None, tool_run)
