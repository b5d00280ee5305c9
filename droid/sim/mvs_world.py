"""The MVS sensor and the tool-tip sensor in the world (thesis §2.5, §5.3-5.4, §6.1).

World devices (``[world.devices.NAME]``, built through droid.sim.world.DEVICE_TYPES):

``fixed_arm``
    An arm twin that does not move: ``wcp = [x, y, z, A, B, C]`` (mm, ZYZ deg),
    its wrist-centre pose in the global frame.  It implements the arm-twin
    interface the sensors need -- ``wcp_global() -> 4x4`` [mm], the arm's
    true wrist-centre pose in the global frame -- and stands in for the arm
    twins until they exist (the real twins keep the device name and the
    interface).

``mvs_camera``
    The laser/camera/DSP board on the welding robot's wrist.  Every 1/60 s of
    world time (to the world step) it computes the sensor frame S in the
    workpiece frame W::

        T_global_S = tool.wcp_global()   @ T_wcp_sensor
        T_global_W = holder.wcp_global() @ T_wcp_workpiece
        T_W_S      = inv(T_global_W) @ T_global_S

    and steps :class:`~droid.sim.mvs_dsp.MvsDspTwin` (render, write the
    board, signal the retrace).  Options::

        dsp = "shm://droid.{cell}.mvs.dsp"    # the board droid-mvs reads
        workpiece = "step_input"              # bundled name or TOML path
        tool_robot = "arm1"                   # device carrying the sensor
        holder_robot = "gmf1"                 # device holding the workpiece
        sensor_pose = [x, y, z, A, B, C]      # T_wcp_sensor (mm, ZYZ deg)
        workpiece_mount = [x, y, z, A, B, C]  # T_wcp_workpiece on the holder
        seed = 1                              # default: [world] seed
        standoff_mm = 150.0                   # laser origin in front of S
        rate_hz = 60.0                        # video frames per second
        [..noise]  jitter_px, spurious_fraction, drop_probability
        [..calibration]  the camera's true pixel <-> mm constants (MvsCalibration)

``tool_sensor``
    The measuring sensor virtually at the tool tip (§6.1): every 1/60 s it
    measures the seam from the tool frame T (``measure``) and writes one line
    in the MVS grammar over its own paced pseudo-terminal, **x = height
    deviation, y = lateral deviation** [mm], then the roll [rad] ("invalid"
    when the tool frame does not see the seam, or the seam point lies off
    the workpiece's extent).  Options: ``serial`` (the symlink the Brain
    opens, e.g. ``"{run}/tool.brain.tty"``), ``baud`` (19200), ``workpiece``,
    ``tool_robot``, ``holder_robot``, ``tool_pose`` (T_wcp_tool),
    ``workpiece_mount``, ``rate_hz``.

:func:`mvs_lockstep` runs the same chain (camera twin -> sensor core -> paced
line -> the Brain's link core -> Status) on a lockstep Scheduler.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, fields
from types import SimpleNamespace
from typing import Any, Mapping

import numpy as np

from droid.brain.layouts import SENSOR_STATUS_LAYOUT
from droid.brain.sensor_line import DEFAULT_BAUD, format_line
from droid.brain.sensor_link import SensorStatusCore
from droid.brain.shmdb import MemoryDatabase
from droid.cli import BadInput
from droid.kinematics.transforms import inv_homo
from droid.sim.device_options import DeviceOptions
from droid.sim.mvs_camera import CameraNoise, MvsCamera
from droid.sim.mvs_dsp import MvsDspTwin, open_dsp_writer
from droid.sim.serial_cable import PacedPipe, PacedPtyOutput
from droid.sim.tool_sensor import ToolReading, measure
from droid.sim.workpiece import Workpiece, load_workpiece
from droid.sim.world import Device
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.wire import COLUMNS, FRAME_RATE_HZ, ROWS

DEFAULT_STANDOFF_MM = 150.0


class FixedArm(Device):
    """An arm twin held at one wrist-centre pose (the arm-twin interface: ``wcp_global()``)."""

    def __init__(self, name: str, T_global_wcp: np.ndarray) -> None:
        self.name = name
        self._T = np.array(T_global_wcp, float)

    def wcp_global(self) -> np.ndarray:
        """The wrist-centre pose in the global frame (4x4, mm)."""
        return self._T.copy()

    def advance(self, dt_s: float) -> None:
        pass


class Mount:
    """A frame on the tool robot's wrist seen from a workpiece on the holder's wrist."""

    def __init__(self, tool_arm, holder_arm, T_wcp_frame: np.ndarray, T_wcp_workpiece: np.ndarray) -> None:
        self.tool_arm = tool_arm
        self.holder_arm = holder_arm
        self.T_wcp_frame = np.asarray(T_wcp_frame, float)
        self.T_wcp_workpiece = np.asarray(T_wcp_workpiece, float)

    def T_global(self) -> np.ndarray:
        """The frame in the global frame (4x4, mm)."""
        return self.tool_arm.wcp_global() @ self.T_wcp_frame

    def T_global_workpiece(self) -> np.ndarray:
        return self.holder_arm.wcp_global() @ self.T_wcp_workpiece

    def T_W(self) -> np.ndarray:
        """The frame in the workpiece frame W: inv(T_global_W) @ T_global_frame (4x4, mm)."""
        return inv_homo(self.T_global_workpiece()) @ self.T_global()


class FrameClock:
    """Fires at ``rate_hz`` against accumulated world time (integer ns, no drift).

    ``advance(dt_s)`` returns True when at least one event fell due in the
    step; events beyond one in a step (a world slower than the rate, or a
    catch-up) are counted in ``skipped``.
    """

    def __init__(self, rate_hz: float) -> None:
        if not rate_hz > 0:
            raise ValueError("rate must be > 0 Hz")
        self.rate_hz = float(rate_hz)
        self.t_ns = 0
        self.fired = 0
        self.skipped = 0
        self._k = 0  # events due so far (the first at t = 0)

    def advance(self, dt_s: float) -> bool:
        self.t_ns += int(round(dt_s * 1e9))
        due = int(self.t_ns * self.rate_hz // 1e9) + 1
        n = due - self._k
        if n <= 0:
            return False
        self._k = due
        self.fired += 1
        self.skipped += n - 1
        return True


class MvsCameraDevice(Device):
    """The MVS camera + DSP board twin on the welding robot (see the module docstring)."""

    def __init__(self, name: str, mount: Mount, twin: MvsDspTwin, rate_hz: float = FRAME_RATE_HZ) -> None:
        self.name = name
        self.mount = mount
        self.twin = twin
        self.clock = FrameClock(rate_hz)
        self.frames = 0
        self.last_T_W_S: np.ndarray | None = None

    def frame(self, t_ns: int) -> np.ndarray | None:
        """Render and deliver one frame for the arms' current poses; the rows or None (dropped)."""
        self.last_T_W_S = self.mount.T_W()
        self.frames += 1
        return self.twin.step(self.last_T_W_S, t_ns)

    def advance(self, dt_s: float) -> None:
        if self.clock.advance(dt_s):
            self.frame(self.clock.t_ns)

    def close(self) -> None:
        self.twin.close()


@dataclass(frozen=True)
class _LineValues:
    x_mm: float
    y_mm: float
    roll_rad: float


class ToolSensorCore:
    """The tool-tip measuring sensor as a core (§6.1): T_W_tool -> one serial line.

    The line is ``height,lateral,roll`` in the MVS grammar (x = height
    deviation [mm], y = lateral deviation [mm], roll [rad]), or ``invalid``.
    """

    def __init__(self, workpiece: Workpiece) -> None:
        self.workpiece = workpiece
        self.last: ToolReading | None = None
        self.lines = 0
        self.valid = 0

    def reading(self, T_W_tool: np.ndarray) -> ToolReading | None:
        """The deviation, or None when the seam point is not on the workpiece."""
        m = measure(T_W_tool, self.workpiece)
        wp = self.workpiece
        if m is None or not (-wp.lead_in_mm <= m.s_mm <= wp.length_mm + wp.lead_out_mm):
            return None
        return m

    def step(self, T_W_tool: np.ndarray) -> bytes:
        self.last = self.reading(T_W_tool)
        values = None if self.last is None else _LineValues(self.last.height_mm, self.last.lateral_mm,
                                                            self.last.roll_rad)
        line = format_line(values)
        self.lines += 1
        self.valid += not line.startswith(b"invalid")
        return line


class IdealSensorCore(ToolSensorCore):
    """The lead sensor as exact geometry (lockstep's ``ideal_sensor``): what a perfect MVS reports.

    Like the tool-tip sensor, plus the field of view of ``calib``: a seam
    point outside the 240 rows x 512 columns reads ``invalid``.
    """

    def __init__(self, workpiece: Workpiece, calib: MvsCalibration) -> None:
        super().__init__(workpiece)
        ys = calib.lateral_of(np.array([0.0, ROWS - 1.0]))
        xs = (np.array([0.0, COLUMNS - 1.0]) - calib.column_at_origin) * calib.depth_mm_per_column
        self.y_range_mm = (float(ys.min()), float(ys.max()))
        self.x_range_mm = (float(xs.min()), float(xs.max()))

    def reading(self, T_W_S: np.ndarray) -> ToolReading | None:
        m = super().reading(T_W_S)
        if m is not None and self.workpiece.gaps and self.workpiece.in_gap(m.s_mm):
            return None  # a gap (issue 15): no feature to find
        if m is None or not (self.y_range_mm[0] <= m.lateral_mm <= self.y_range_mm[1]
                             and self.x_range_mm[0] <= m.height_mm <= self.x_range_mm[1]):
            return None
        return m


class ToolSensorDevice(Device):
    """The tool-tip sensor in the world: core + mount + a paced serial output."""

    def __init__(self, name: str, mount: Mount, core: ToolSensorCore, output, rate_hz: float = FRAME_RATE_HZ) -> None:
        self.name = name
        self.mount = mount
        self.core = core
        self.output = output
        self.clock = FrameClock(rate_hz)

    def line(self) -> bytes:
        """Measure now and return the line (for lockstep, which delivers it itself)."""
        return self.core.step(self.mount.T_W())

    def advance(self, dt_s: float) -> None:
        if self.clock.advance(dt_s):
            self.output.write(self.line())
        self.output.advance(dt_s)

    def close(self) -> None:
        self.output.close()


# -- factories (droid.sim.world.DEVICE_TYPES) -----------------------------------

def fixed_arm(world, name: str, options: dict[str, Any]) -> FixedArm:
    opts = DeviceOptions(world, name, options)
    T = opts.pose("wcp")
    opts.done()
    return FixedArm(name, T)


def _mount(opts: DeviceOptions, pose_key: str) -> Mount:
    tool = opts.device("tool_robot")
    holder = opts.device("holder_robot")
    return Mount(tool, holder, opts.pose(pose_key), opts.pose("workpiece_mount"))


def _workpiece(opts: DeviceOptions) -> Workpiece:
    return load_workpiece(opts.get("workpiece", str, "step_input"))


def _positive(v) -> str | None:
    return None if v > 0 else "must be > 0"


def _camera(opts: DeviceOptions, dsp_url: str) -> MvsCameraDevice:
    mount = _mount(opts, "sensor_pose")
    workpiece = _workpiece(opts)
    noise_table = opts.get("noise", dict, {})
    known = {f.name for f in fields(CameraNoise)}
    if set(noise_table) - known:
        raise opts.bad(f"unknown key(s) {', '.join(sorted(set(noise_table) - known))} "
                       f"(expected {', '.join(sorted(known))})", "noise")
    try:
        noise = CameraNoise(**{k: float(v) for k, v in noise_table.items()})
    except (TypeError, ValueError):
        raise opts.bad("jitter_px must be >= 0, spurious_fraction and drop_probability within [0, 1]",
                       "noise") from None
    calib = MvsCalibration.from_table(opts.get("calibration", dict, {}), source=f"{opts.where} calibration")
    standoff = opts.get("standoff_mm", float, DEFAULT_STANDOFF_MM, check=_positive)
    rate = opts.get("rate_hz", float, FRAME_RATE_HZ, check=_positive)
    seed = opts.get("seed", int, int(getattr(opts.world, "seed", 0)))
    opts.done()
    writer = open_dsp_writer(dsp_url)
    twin = MvsDspTwin(MvsCamera(workpiece, calib, noise, standoff), writer, seed)
    return MvsCameraDevice(opts.name, mount, twin, rate)


def mvs_camera(world, name: str, options: dict[str, Any]) -> MvsCameraDevice:
    opts = DeviceOptions(world, name, options)
    return _camera(opts, opts.get("dsp", str))


def _tool_parts(opts: DeviceOptions) -> tuple[Mount, ToolSensorCore, float]:
    mount = _mount(opts, "tool_pose")
    core = ToolSensorCore(_workpiece(opts))
    rate = opts.get("rate_hz", float, FRAME_RATE_HZ, check=_positive)
    return mount, core, rate


def tool_sensor(world, name: str, options: dict[str, Any]) -> ToolSensorDevice:
    opts = DeviceOptions(world, name, options)
    mount, core, rate = _tool_parts(opts)
    path = opts.get("serial", str)
    baud = opts.get("baud", int, DEFAULT_BAUD, check=_positive)
    opts.done()
    return ToolSensorDevice(name, mount, core, PacedPtyOutput(path, baud), rate)


# -- lockstep ----------------------------------------------------------------------

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
                 tool: dict[str, Any] | None = None, *, seed: int = 0, stale_ticks: int = 3,
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
    (:func:`~droid.sim.tool_sensor.measure` at S, as the tool-tip sensor
    reports it), ``invalid`` outside the sensor calibration's field of view.
    No pixels, no noise; use it where only the geometry matters.
    """
    from droid.sim.lockstep import ORDER_DEVICE, ORDER_WORLD
    from droid.subunits.mvs.dsp import open_dsp
    from droid.subunits.mvs.sensor import SensorCore

    uid = next(_LOCKSTEP_IDS)
    world = SimpleNamespace(devices=dict(devices), seed=seed, cell=None)
    cam_opts = dict(camera)
    if "dsp" in cam_opts:
        raise BadInput("mvs_lockstep: camera option 'dsp' is chosen by the lockstep runner")
    url = f"inproc://{name}.{uid}.mvs.dsp"
    cam = _camera(DeviceOptions(world, "mvs_camera", cam_opts), url)
    board = open_dsp(url)
    calib = MvsCalibration.from_table(sensor_calibration or {}, source="mvs_lockstep sensor_calibration")
    sensor = SensorCore(calib)

    def chain(what: str) -> SensorChain:
        return SensorChain(PacedPipe(baud), SensorStatusCore(stale_ticks),
                           MemoryDatabase(f"/{name}.{what}.status", SENSOR_STATUS_LAYOUT))

    run = MvsLockstep(cam, sensor, board, chain("mvs"))
    if tool is not None:
        opts = DeviceOptions(world, "tool_sensor", dict(tool))
        mount, core, rate = _tool_parts(opts)
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
        scheduler.every(tool_dev.clock.rate_hz, lambda t_ns: tool_chain.pipe.write(tool_dev.line(), t_ns),
                        f"{name}.tool_sensor", order=ORDER_WORLD)
        scheduler.on_tick(link_task(tool_chain), f"{name}.tool_link")
    return run
