"""The MVS camera and the tool-tip sensor as world devices (thesis §2.5, §5.3-5.4, §6.1).

World devices (``[world.devices.NAME]``, built through droid.sim.world.DEVICE_TYPES):

``fixed_arm`` (:mod:`droid.sim.mvs.arm`)
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

    and steps :class:`~droid.sim.mvs.dsp.MvsDspTwin` (render, write the
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
    ``workpiece_mount``, ``rate_hz``, ``seed`` (default: [world] seed + 1) and
    ``[..noise]`` -- the lead sensor's noise keys (jitter_px,
    spurious_fraction, drop_probability), turned into the ideal sensor
    model's equivalent scatter (``tool_sensor.ToolNoise.like_camera``;
    default: none, exact), ``stamp`` (true: each line carries its capture
    time, ``x,y,roll,ms`` -- CLOCK_MONOTONIC ms modulo 100000 at the
    measurement, the clock the Brain shares on one host, as
    ``droid-mvs --stamp``; default false: the thesis's plain lines).

:func:`droid.sim.mvs.lockstep.mvs_lockstep` runs the same chain (camera twin ->
droid-mvs's station -> paced line -> the Brain's link core -> Status) on a lockstep
Scheduler.  ``fixed_arm`` is :mod:`droid.sim.mvs.arm`, the mounts
:mod:`droid.sim.mvs.mounts`, the 60 Hz clock :mod:`droid.sim.mvs.clock`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from droid.brain.plumbing.sensor_line import DEFAULT_BAUD, format_line, stamp_ms_of
from droid.sim.device_options import DeviceOptions
from droid.sim.mvs.camera import CameraNoise, MvsCamera
from droid.sim.mvs.clock import FrameClock
from droid.sim.mvs.dsp import MvsDspTwin, open_dsp_writer
from droid.sim.mvs.mounts import Mount
from droid.sim.mvs.tool_sensor import ToolNoise, ToolReading, measure, noisy
from droid.sim.serial_cable import PacedPtyOutput
from droid.sim.workpiece import Workpiece, load_workpiece
from droid.sim.device import Device
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.wire import COLUMNS, FRAME_RATE_HZ, ROWS

DEFAULT_STANDOFF_MM = 150.0


def pose_key(T: np.ndarray) -> tuple:
    """A pose's exact identity (dtype, shape and bytes): equal keys, the same bits."""
    a = np.asarray(T)
    return a.dtype.str, a.shape, a.tobytes()


class MvsCameraDevice(Device):
    """The MVS camera + DSP board twin on the welding robot (see the module docstring)."""
    step_s = 0.004  # its frames (60 Hz) keep their rate on world time; the frame is taken at the step's end

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
    deviation [mm], y = lateral deviation [mm], roll [rad]), or ``invalid``;
    the values through ``noise`` (seeded by ``seed``: deterministic).
    """

    def __init__(self, workpiece: Workpiece, noise: ToolNoise = ToolNoise(), seed: int = 0,
                 stamp: bool = False) -> None:
        self.workpiece = workpiece
        self.noise = noise
        self.stamp = stamp
        self.rng = np.random.default_rng(seed)
        self.last: ToolReading | None = None
        self.lines = 0
        self.valid = 0
        self._seen: tuple | None = None  # (pose key, workpiece, reading) of the last step (see step)

    def reading(self, T_W_tool: np.ndarray) -> ToolReading | None:
        """The deviation, or None when the seam point is not on the workpiece."""
        m = measure(T_W_tool, self.workpiece)
        wp = self.workpiece
        if m is None or not (-wp.lead_in_mm <= m.s_mm <= wp.length_mm + wp.lead_out_mm):
            return None
        return m

    def step(self, T_W_tool: np.ndarray, t_ns: int | None = None) -> bytes:
        """The line of a measurement at ``T_W_tool``; stamped with ``t_ns`` [ns, the capture
        instant on the cell's clock] when the core stamps and it is given."""
        # the reading is a function of the pose alone: a pose unchanged to the bit (an arm and a
        # holder at rest) reads what it read last time; the noise is drawn every line regardless
        key = pose_key(T_W_tool)
        seen = self._seen
        if seen is None or seen[0] != key or seen[1] is not self.workpiece:
            seen = self._seen = (key, self.workpiece, self.reading(T_W_tool))
        self.last = noisy(seen[2], self.noise, self.rng)
        values = None if self.last is None else _LineValues(self.last.height_mm, self.last.lateral_mm,
                                                            self.last.roll_rad)
        line = format_line(values, stamp_ms_of(t_ns) if (self.stamp and t_ns is not None) else None)
        self.lines += 1
        self.valid += not line.startswith(b"invalid")
        return line


class IdealSensorCore(ToolSensorCore):
    """The lead sensor as exact geometry (lockstep's ``ideal_sensor``): what a perfect MVS reports.

    Like the tool-tip sensor, plus the field of view of ``calib``: a seam
    point outside the 240 rows x 512 columns reads ``invalid``.
    """

    def __init__(self, workpiece: Workpiece, calib: MvsCalibration) -> None:
        super().__init__(workpiece)  # exact: lockstep's ideal_sensor has no noise
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
    step_s = 0.004  # its lines (60 Hz) and their bytes (19200 baud: ~8 a step) keep their rates

    def __init__(self, name: str, mount: Mount, core: ToolSensorCore, output, rate_hz: float = FRAME_RATE_HZ,
                 clock_ns=time.monotonic_ns) -> None:
        self.name = name
        self.mount = mount
        self.core = core
        self.output = output
        self.clock = FrameClock(rate_hz)
        self.clock_ns = clock_ns  # the capture stamp's clock (the cell's CLOCK_MONOTONIC in real time)

    def line(self, t_ns: int | None = None) -> bytes:
        """Measure now and return the line, stamped with ``t_ns`` [ns] when the core stamps (for
        lockstep, which delivers it itself on virtual time)."""
        return self.core.step(self.mount.T_W(), t_ns)

    def advance(self, dt_s: float) -> None:
        if self.clock.advance(dt_s):
            self.output.write(self.line(self.clock_ns() if self.core.stamp else None))
        self.output.advance(dt_s)

    def close(self) -> None:
        self.output.close()



def _mount(opts: DeviceOptions, pose_key: str) -> Mount:
    tool = opts.device("tool_robot")
    holder = opts.device("holder_robot")
    return Mount(tool, holder, opts.pose(pose_key), opts.pose("workpiece_mount"))


def _workpiece(opts: DeviceOptions) -> Workpiece:
    return load_workpiece(opts.get("workpiece", str, "step_input"))


def _positive(v) -> str | None:
    return None if v > 0 else "must be > 0"


def _camera_noise(opts: DeviceOptions) -> CameraNoise:
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
    return noise


def build_camera(opts: DeviceOptions, dsp_url: str) -> MvsCameraDevice:
    mount = _mount(opts, "sensor_pose")
    workpiece = _workpiece(opts)
    noise = _camera_noise(opts)
    calib = MvsCalibration.from_table(opts.get("calibration", dict, {}), source=f"{opts.where} calibration")
    standoff = opts.get("standoff_mm", float, DEFAULT_STANDOFF_MM, check=_positive)
    rate = opts.get("rate_hz", float, FRAME_RATE_HZ, check=_positive)
    seed = opts.get("seed", int, int(getattr(opts.world, "seed", 0)))
    opts.done()
    writer = open_dsp_writer(dsp_url)
    twin = MvsDspTwin(MvsCamera(workpiece, calib, noise, standoff), writer, seed)
    return MvsCameraDevice(opts.name, mount, twin, rate)


def publish_workpiece_mesh(world, workpiece: Workpiece) -> None:
    """Write the workpiece's surfaces (:func:`droid.sim.workpiece_mesh.workpiece_mesh`, plain data
    in the workpiece frame W) to ``{run}/workpiece_mesh.json``, where droid-web reads it for a live
    cell (an observer may not import the simulator, docs/design.md §7; a file of data it may read).  Only
    when the run directory exists (a running cell); written whole (rename), never half."""
    import json
    import os

    from droid.brain.cell.cellfile import WORKPIECE_MESH_FILE
    from droid.sim.workpiece_mesh import workpiece_mesh

    run_dir = getattr(getattr(world, "cell", None), "run_dir", None)
    if run_dir is None or not os.path.isdir(run_dir):
        return
    path = os.path.join(run_dir, WORKPIECE_MESH_FILE)
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "w") as f:
        json.dump(workpiece_mesh(workpiece), f)
    os.replace(tmp, path)


def mvs_camera(world, name: str, options: dict[str, Any]) -> MvsCameraDevice:
    opts = DeviceOptions(world, name, options)
    dev = build_camera(opts, opts.get("dsp", str))
    publish_workpiece_mesh(world, dev.twin.camera.workpiece)
    return dev


def tool_parts(opts: DeviceOptions) -> tuple[Mount, ToolSensorCore, float]:
    mount = _mount(opts, "tool_pose")
    noise = ToolNoise.like_camera(_camera_noise(opts))
    seed = opts.get("seed", int, int(getattr(opts.world, "seed", 0)) + 1)
    stamp = opts.get("stamp", bool, False)
    core = ToolSensorCore(_workpiece(opts), noise, seed, stamp)
    rate = opts.get("rate_hz", float, FRAME_RATE_HZ, check=_positive)
    return mount, core, rate


def tool_sensor(world, name: str, options: dict[str, Any]) -> ToolSensorDevice:
    opts = DeviceOptions(world, name, options)
    mount, core, rate = tool_parts(opts)
    path = opts.get("serial", str)
    baud = opts.get("baud", int, DEFAULT_BAUD, check=_positive)
    opts.done()
    return ToolSensorDevice(name, mount, core, PacedPtyOutput(path, baud), rate)


