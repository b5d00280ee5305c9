"""One seam-tracking trial in lockstep (thesis §6.1): one process, virtual time, deterministic per seed.

Composition on a :class:`droid.sim.lockstep.Scheduler` (60 Hz heartbeat):

====================  ===============  ==================================================
what                  when             does
====================  ===============  ==================================================
Reis arm              every tick       ``full`` (arm_full, the default: every Reis core + the
                                       plant twin, homed from its power-up pose first) or
                                       ``fast`` (arm_fast: planner + analytic servo)
GMF1                  every tick       holds the workpiece still at its start pose, or drifts at
                                       ``holder_mm_s`` (the holder-moving test of plus mode)
lead sensor           the tick before  the frame the next cycle reads (sensors.LeadSensor),
                      each cycle       stamped with its capture tick; ``latency_cycles`` holds
                                       every reading back that many cycles
tool-tip sensor       the tick before  the sample the next log row shows
                      each log row
tracking cycle        every tick:      droid.tasks.seam.cycle.TrackingCycle -- the same code as
                      poses; every     droid-seamtrack: pose histories, cycle counting from the
                      cycle_ticks      heartbeat, the reading placed with the poses of its
                      (30 Hz): step    capture, the core of the mode (thesis, listing, plus)
                                       -> Reis cart command (one cycle of ticks)
log                   every log_ticks  one CSV row (10 Hz, thesis §6.1)
====================  ===============  ==================================================

Within a tick the order is: arm (its state at the tick), sensors (the true
poses at the tick), then the task -- as ORDER_WORLD < ORDER_DEVICE < ORDER_TASK.

The trial ends when the core stops (end of seam: the run length reached;
seam lost; a Reis command out of reach) or after a time limit (``timeout``).
"""
from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from droid.cli import BadInput
from droid.kinematics.transforms import inv_homo
from droid.sim.experiment.arm_fast import FastArm, FastArmParams
from droid.sim.experiment.geometry import TrialGeometry, trial_geometry
from droid.sim.experiment.sensors import DEFAULT_NOISE, SENSOR_MODELS, LeadSensor, tool_reading
from droid.sim.lockstep import ORDER_DEVICE, ORDER_TASK, ORDER_WORLD, Scheduler
from droid.sim.mvs.camera import CameraNoise
from droid.tasks.seam.core import DEAD_ZONE_CYCLES, LOST_CYCLES, MAX_SPEED_MM_S, MODE_THESIS, MODES, SeamParams
from droid.tasks.seam.cycle import TrackingCycle
from droid.tasks.seam.delay import INVALID_READING, Reading
from droid.tasks.seam.report import COLUMNS, SETTLE_EXTRA_MM, log_row  # noqa: F401 (columns; settling)

ARM_MODELS = ("fast", "full")
HEARTBEAT_HZ = 60.0
CYCLE_TICKS = 2  # one 30 Hz seam-tracking cycle = 2 heartbeat ticks (cart_time_count; TrackingCycle.cycle_ticks)
LOG_TICKS = 6  # 10 Hz log (TrackingCycle.log_ticks)
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
    arm: str = "full"  # the Reis model: full (every core + the plant twin; homes first) or fast
    sensor: str = "camera"
    noise: CameraNoise = DEFAULT_NOISE
    dead_zone_cycles: int = DEAD_ZONE_CYCLES
    lost_cycles: int = LOST_CYCLES
    fast_params: FastArmParams = FastArmParams()
    title: str = ""
    panels: str = "errors"  # "errors" (Figs 6.5-6.13) or "angles" (Figs 6.17-6.35: yaw/pitch panels)
    mode: str = MODE_THESIS  # tracking mode: thesis, listing, plus (docs/seamtrack.md)
    holder_mm_s: tuple = (0.0, 0.0, 0.0)  # the GMF1 wrist centre drifting at this global velocity [mm/s]
    latency_cycles: int = 0  # constant extra latency of every lead reading [30 Hz cycles] (stamped)

    def __post_init__(self) -> None:
        if self.arm not in ARM_MODELS:
            raise BadInput(f"unknown arm model {self.arm!r} (known: {', '.join(ARM_MODELS)})")
        if self.mode not in MODES:
            raise BadInput(f"unknown mode {self.mode!r} (known: {', '.join(MODES)})")
        if self.sensor not in SENSOR_MODELS:
            raise BadInput(f"unknown sensor model {self.sensor!r} (known: {', '.join(SENSOR_MODELS)})")
        for name in ("speed_mm_s", "yaw_gain", "pitch_gain", "delay_at_mm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise BadInput(f"trial {self.trial_id}: {name} must be a finite number, got {v!r}")
        if self.speed_mm_s <= 0:
            raise BadInput(f"trial {self.trial_id}: speed must be > 0 mm/s")
        if self.speed_mm_s > MAX_SPEED_MM_S:
            raise BadInput(f"trial {self.trial_id}: speed {self.speed_mm_s:g} mm/s is beyond what the arm can do "
                           f"(at most {MAX_SPEED_MM_S:g} mm/s)")
        if len(self.holder_mm_s) != 3 or not all(math.isfinite(v) for v in self.holder_mm_s):
            raise BadInput(f"trial {self.trial_id}: holder_mm_s must be 3 finite numbers [mm/s]")
        if not isinstance(self.latency_cycles, int) or self.latency_cycles < 0:
            raise BadInput(f"trial {self.trial_id}: latency_cycles must be an integer >= 0")


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
    prep_s: float = 0.0  # simulated seconds before the trial: the full arm's homing, move to the start, settling
    wall_s: float = 0.0
    camera_to_tcp_mm: float = 100.0
    frames: int = 0
    valid_frames: int = 0
    dropped: int = 0  # lead readings dropped by the tracking cycle (instant outside the pose history)

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
                        delay_cycles=cfg.delay_cycles, delay_at_mm=cfg.delay_at_mm, mode=cfg.mode)
    sched = Scheduler(HEARTBEAT_HZ)
    if cfg.arm == "fast":
        arm = FastArm(geo.reis, geo.q_reis_start_deg, cfg.fast_params)
    else:
        from droid.sim.experiment.arm_full import FullArm

        arm = FullArm(sched, geo.reis, geo.q_reis_start_deg, seed=cfg.seed)
        arm.prepare()
    try:
        cyc = TrackingCycle(params, geo.wrist.T_wcp_tool, geo.wrist.T_wcp_sensor, geo.reis,
                            heartbeat_hz=HEARTBEAT_HZ)
    except ValueError as exc:
        raise BadInput(f"trial {cfg.trial_id}: {exc}") from None
    lead = LeadSensor(geo.workpiece, cfg.sensor, cfg.noise, seed=cfg.seed)
    result = TrialResult(cfg, camera_to_tcp_mm=L)
    T_hold0 = geo.T_global_hold6
    v_hold = np.asarray(cfg.holder_mm_s, float)
    moving_holder = bool(np.any(v_hold != 0.0))
    T_wcp_sensor, T_wcp_tool = geo.wrist.T_wcp_sensor, geo.wrist.T_wcp_tool
    crossing = lead.crossing
    t0_tick = sched.tick
    ct, lt = cyc.cycle_ticks, cyc.log_ticks
    state = {"lead": INVALID_READING, "lead_tick": 0, "tool": None, "out": None, "done": False,
             "T_hold": T_hold0, "T_W_g": inv_homo(T_hold0 @ geo.T_hold6_W)}
    in_flight: deque = deque()  # (reading, Status tick) of the constant extra latency

    def hold_at(k: int) -> None:
        """The holder's pose at trial tick k (it drifts at ``holder_mm_s``)."""
        if moving_holder:
            T = T_hold0.copy()
            T[:3, 3] += v_hold * (k / HEARTBEAT_HZ)
            state["T_hold"], state["T_W_g"] = T, inv_homo(T @ geo.T_hold6_W)

    def s_of(m) -> float:
        return m.s_mm + L  # seam progress of the tool: 0 at the start (tool at s = -CAMERA_TO_TCP)

    def sensors(tick: int) -> None:
        k = tick - t0_tick
        hold_at(k)
        T_W_g = state["T_W_g"]
        if k % ct == ct - 1:  # the frame the next cycle reads (it reaches the Status next tick)
            T_true = arm.true_wcp()
            r = lead.read(T_W_g @ T_true @ T_wcp_sensor)
            if r.valid:
                r = replace(r, stamp_tick=float(tick))  # the MVS world's frame stamp: its capture tick
            in_flight.append((r, tick + 1))
            while len(in_flight) > cfg.latency_cycles:
                state["lead"], state["lead_tick"] = in_flight.popleft()
        if k % lt == lt - 1:
            state["tool"] = tool_reading(T_W_g @ arm.true_wcp() @ T_wcp_tool, crossing)

    recorder = None
    if record is not None:
        from droid.observe.lockstep import TrialRecorder

        recorder = TrialRecorder(record, cfg.trial_id, geo.reis, geo.fanuc, T_wcp_tool, T_wcp_sensor, geo.T_hold6_W,
                                 geo.q_hold_deg, T_hold0)

    def task(tick: int) -> None:
        if recorder is not None:
            recorder.sample(tick, sched.t_ns, arm, state)
        if state["done"]:
            return
        k = tick - t0_tick
        T_reis = arm.status_pose()
        cyc.remember(tick, T_reis, tick, state["T_hold"])
        if k >= ct and cyc.due(tick):
            out = cyc.step(state["T_hold"], T_reis, tick, state["lead"], state["lead_tick"], arm.status_joints())
            state["out"] = out
            if out.stop is not None:
                state["done"] = True
                m = tool_reading(state["T_W_g"] @ arm.true_wcp() @ T_wcp_tool, crossing)
                result.stop_reason, result.stop_detail = out.stop.reason, out.stop.detail
                result.stop_s_mm = s_of(m) if m is not None else math.nan
                result.stop_t_s = (sched.t_ns / 1e9)
                return
            arm.command_cart(out.reis_cmd, ct)
        if k >= 1 and cyc.log_due(tick):
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
        m = tool_reading(state["T_W_g"] @ arm.true_wcp() @ T_wcp_tool, crossing)
        result.stop_s_mm = s_of(m) if m is not None else math.nan
    result.stop_t_s -= t_start
    result.sim_s = sched.t_ns / 1e9 - t_start
    result.prep_s = t_start
    result.frames, result.valid_frames = lead.frames, lead.valid
    result.dropped = cyc.dropped
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
