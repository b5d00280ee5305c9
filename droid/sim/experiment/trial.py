"""One seam-tracking trial in lockstep (thesis §6.1): one process, virtual time, deterministic per seed.

Composition on a :class:`droid.sim.lockstep.Scheduler` (60 Hz heartbeat):

====================  ===============  ==================================================
what                  when             does
====================  ===============  ==================================================
Reis arm              every tick       ``fast`` (arm_fast: planner + analytic servo) or
                                       ``full`` (arm_full: every Reis core + the plant)
GMF1                  --               holds the workpiece still at its start pose
lead sensor           odd ticks        the frame the next cycle reads (sensors.LeadSensor)
tool-tip sensor       ticks 5 mod 6    the sample the next log row shows
seam-tracking core    even ticks       droid.tasks.seam.SeamTracker: Status poses +
                      (30 Hz)          the lead reading -> Reis cart command (2 ticks)
log                   every 6th tick   one CSV row (10 Hz, thesis §6.1)
====================  ===============  ==================================================

Within a tick the order is: arm (its state at the tick), sensors (the true
poses at the tick), then the task -- as ORDER_WORLD < ORDER_DEVICE < ORDER_TASK.

The trial ends when the core stops (end of seam: the run length reached;
seam lost; a Reis command out of reach) or after a time limit (``timeout``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from droid.cli import BadInput
from droid.kinematics.transforms import inv_homo
from droid.sim.experiment.arm_fast import FastArm, FastArmParams
from droid.sim.experiment.geometry import TrialGeometry, trial_geometry
from droid.sim.experiment.sensors import DEFAULT_NOISE, SENSOR_MODELS, LeadSensor, tool_reading
from droid.sim.lockstep import ORDER_DEVICE, ORDER_TASK, ORDER_WORLD, Scheduler
from droid.sim.mvs_camera import CameraNoise
from droid.tasks.seam.core import DEAD_ZONE_CYCLES, LOST_CYCLES, SeamParams, SeamTracker
from droid.tasks.seam.delay import INVALID_READING, Reading
from droid.tasks.seam.report import COLUMNS, SETTLE_EXTRA_MM, log_row  # noqa: F401 (columns; settling)

ARM_MODELS = ("fast", "full")
HEARTBEAT_HZ = 60.0
CYCLE_TICKS = 2  # one 30 Hz seam-tracking cycle = 2 heartbeat ticks (cart_time_count)
LOG_TICKS = 6  # 10 Hz log
#: Time limit of a trial: this many times run length / nominal speed, + 30 s.  The tool
#: advances at only ~47 % of the nominal speed (the core targets ``vel`` mm ahead of the
#: tool pose the Status reports, which trails the command: servo lag and Status sampling),
#: so 1.8 timed the 4 mm/s ramps out.
TIME_LIMIT_FACTOR = 3.0


@dataclass(frozen=True)
class TrialConfig:
    """Everything that defines one trial (the experiment matrix fills these in)."""

    trial_id: str
    position: str
    speed_mm_s: float
    workpiece: str | None = None  # None: the position's own (droid/cells/seamtrack_layout.toml)
    yaw_gain: float = 0.15
    pitch_gain: float = 0.25
    delay_cycles: int = 0
    delay_at_mm: float = 150.0
    wrist: str = "standard"
    length_mm: float | None = None  # tool travel to the end; None: the workpiece's seam length
    seed: int = 1
    arm: str = "fast"
    sensor: str = "camera"
    noise: CameraNoise = DEFAULT_NOISE
    dead_zone_cycles: int = DEAD_ZONE_CYCLES
    lost_cycles: int = LOST_CYCLES
    fast_params: FastArmParams = FastArmParams()
    title: str = ""
    panels: str = "errors"  # "errors" (Figs 6.5-6.13) or "angles" (Figs 6.17-6.35: yaw/pitch panels)

    def __post_init__(self) -> None:
        if self.arm not in ARM_MODELS:
            raise BadInput(f"unknown arm model {self.arm!r} (known: {', '.join(ARM_MODELS)})")
        if self.sensor not in SENSOR_MODELS:
            raise BadInput(f"unknown sensor model {self.sensor!r} (known: {', '.join(SENSOR_MODELS)})")
        for name in ("speed_mm_s", "yaw_gain", "pitch_gain", "delay_at_mm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise BadInput(f"trial {self.trial_id}: {name} must be a finite number, got {v!r}")
        if self.speed_mm_s <= 0:
            raise BadInput(f"trial {self.trial_id}: speed must be > 0 mm/s")


@dataclass
class TrialResult:
    """The log and outcome of one trial."""

    config: TrialConfig
    rows: list[tuple] = field(default_factory=list)
    stop_reason: str = ""
    stop_detail: str = ""
    stop_s_mm: float = math.nan
    stop_t_s: float = math.nan
    sim_s: float = 0.0
    wall_s: float = 0.0
    camera_to_tcp_mm: float = 100.0
    frames: int = 0
    valid_frames: int = 0

    def column(self, name: str) -> np.ndarray:
        """One numeric column of the log as a float array."""
        i = COLUMNS.index(name)
        return np.array([r[i] for r in self.rows], dtype=float)

    @property
    def speedup(self) -> float:
        """Simulated seconds per wall second."""
        return self.sim_s / self.wall_s if self.wall_s > 0 else math.inf


def default_length_mm(geo: TrialGeometry) -> float:
    """Run length: the tool's travel until the lead sensor reaches the seam's end."""
    return geo.workpiece.length_mm


def run_trial(cfg: TrialConfig, layout=None, record: str | None = None) -> TrialResult:
    """Run one trial in lockstep and return its log (see the module docstring); ``record``: also
    write an MCAP recording of it there (droid.observe.lockstep, docs/observe.md)."""
    wall0 = time.perf_counter()
    geo = trial_geometry(cfg.position, cfg.workpiece, cfg.wrist, layout)
    L = geo.camera_to_tcp_mm
    length = cfg.length_mm if cfg.length_mm is not None else default_length_mm(geo)
    params = SeamParams(speed_mm_s=cfg.speed_mm_s, yaw_gain=cfg.yaw_gain, pitch_gain=cfg.pitch_gain,
                        dead_zone_cycles=cfg.dead_zone_cycles, lost_cycles=cfg.lost_cycles, length_mm=length,
                        delay_cycles=cfg.delay_cycles, delay_at_mm=cfg.delay_at_mm)
    sched = Scheduler(HEARTBEAT_HZ)
    if cfg.arm == "fast":
        arm = FastArm(geo.reis, geo.q_reis_start_deg, cfg.fast_params)
    else:
        from droid.sim.experiment.arm_full import FullArm

        arm = FullArm(sched, geo.reis, geo.q_reis_start_deg, seed=cfg.seed)
        arm.prepare()
    core = SeamTracker(params, geo.wrist.T_wcp_tool, geo.wrist.T_wcp_sensor, geo.reis)
    lead = LeadSensor(geo.workpiece, cfg.sensor, cfg.noise, seed=cfg.seed)
    result = TrialResult(cfg, camera_to_tcp_mm=L)
    T_hold = geo.T_global_hold6  # the holder does not move
    T_W_g = inv_homo(T_hold @ geo.T_hold6_W)
    T_wcp_sensor, T_wcp_tool = geo.wrist.T_wcp_sensor, geo.wrist.T_wcp_tool
    crossing = lead.crossing
    t0_tick = sched.tick
    state = {"lead": INVALID_READING, "tool": None, "out": None, "done": False, "s0": None}

    def s_of(m) -> float:
        return m.s_mm + L  # seam progress of the tool: 0 at the start (tool at s = -CAMERA_TO_TCP)

    def sensors(tick: int) -> None:
        k = tick - t0_tick
        if k % CYCLE_TICKS == 1:
            T_true = arm.true_wcp()
            state["lead"] = lead.read(T_W_g @ T_true @ T_wcp_sensor)
            if k % LOG_TICKS == LOG_TICKS - 1:
                state["tool"] = tool_reading(T_W_g @ T_true @ T_wcp_tool, crossing)

    recorder = None
    if record is not None:
        from droid.observe.lockstep import TrialRecorder

        recorder = TrialRecorder(record, cfg.trial_id, geo.reis, geo.fanuc, T_wcp_tool, T_wcp_sensor, geo.T_hold6_W,
                                 geo.q_hold_deg, T_hold)

    def task(tick: int) -> None:
        if recorder is not None:
            recorder.sample(tick, sched.t_ns, arm, state)
        if state["done"]:
            return
        k = tick - t0_tick
        if k % CYCLE_TICKS == 0 and k > 0:
            out = core.step(T_hold, arm.status_pose(), state["lead"], arm.status_joints())
            state["out"] = out
            if out.stop is not None:
                state["done"] = True
                m = tool_reading(T_W_g @ arm.true_wcp() @ T_wcp_tool, crossing)
                result.stop_reason, result.stop_detail = out.stop.reason, out.stop.detail
                result.stop_s_mm = s_of(m) if m is not None else math.nan
                result.stop_t_s = (sched.t_ns / 1e9)
                return
            arm.command_cart(out.reis_cmd, CYCLE_TICKS)
        if k % LOG_TICKS == 0 and k > 0:
            result.rows.append(_row(sched.t_ns / 1e9 - t_start, state["lead"], state["tool"], state["out"], L,
                                    s_of))

    t_start = sched.t_ns / 1e9
    sched.on_tick(lambda tick: arm.tick(), "arm", order=ORDER_WORLD)
    sched.on_tick(sensors, "sensors", order=ORDER_DEVICE)
    sched.on_tick(task, "seamtrack", order=ORDER_TASK)
    limit_s = TIME_LIMIT_FACTOR * length / cfg.speed_mm_s + 30.0
    while not state["done"] and sched.t_ns / 1e9 - t_start < limit_s:
        sched.run_ticks(60)
    if not state["done"]:
        result.stop_reason, result.stop_detail = "timeout", f"no end within {limit_s:.0f} s"
        result.stop_t_s = sched.t_ns / 1e9
        m = tool_reading(T_W_g @ arm.true_wcp() @ T_wcp_tool, crossing)
        result.stop_s_mm = s_of(m) if m is not None else math.nan
    result.stop_t_s -= t_start
    result.sim_s = sched.t_ns / 1e9 - t_start
    result.frames, result.valid_frames = lead.frames, lead.valid
    if recorder is not None:
        recorder.close()
    result.wall_s = time.perf_counter() - wall0
    return result


def _row(t_s: float, lead: Reading, tool, out, L: float, s_of) -> tuple:
    """The 10 Hz log row: ``s_mm`` from the tool-tip sensor's seam coordinate (the truth)."""
    t = None if tool is None else (tool.lateral_mm, tool.height_mm, tool.roll_rad)
    return log_row(s_mm=s_of(tool) if tool is not None else math.nan, t_s=t_s, lead=lead, tool=t, out=out,
                   camera_to_tcp_mm=L)


def with_overrides(cfg: TrialConfig, **kw) -> TrialConfig:
    return replace(cfg, **kw)
