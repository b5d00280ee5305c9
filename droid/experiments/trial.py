"""One seam-tracking trial in lockstep (thesis §6.1): one process, virtual time, deterministic per seed.

Composition on a :class:`droid.sim.lockstep.Scheduler` (60 Hz heartbeat):

====================  ===============  ==================================================
what                  when             does
====================  ===============  ==================================================
Reis arm              every tick       ``full`` (sim.trial_cell.FullArm, the default: every Reis core + the
                                       plant twin, homed from its power-up pose first) or
                                       ``fast`` (sim.reis.fast_arm: planner + analytic servo).  With
                                       ``cell`` (a cell file): the cell's welder, its layout's
                                       tool_robot -- the Reis, or the ABB on EGM (droid-egm and
                                       its controller twin, sim.abb.lockstep; full only) --
                                       and its holder (sim.trial_cell)
GMF1                  its own rates    ``holder="gmf1"`` (default): the Fanuc twin (KAREL, its
                                       path, the arm of its robot file) and the GMF1 programs'
                                       cores (experiment.holder); homed and moved to the holding
                                       pose first, the tracker reads its Status pose, the sensors
                                       see its true pose; with ``holder_mm_s`` one cartesian
                                       MOVE through KAREL at that velocity from the start.
                                       ``"fixed"``: the exact holding pose, drifting at
                                       ``holder_mm_s`` (no controller, no encoders)
lead sensor           the tick before  the frame the next cycle reads (the ``lead`` model of the
                      each cycle       layout's sensor's package, sim.trial_cell.TrialCell.lead_sensor:
                                       the MVS's, sim.mvs.trial_sensors.LeadSensor),
                                       stamped with its capture tick; ``latency_cycles`` holds
                                       every reading back that many cycles; a frame that brings
                                       no line (droid-mvs's station: dropped, inside the retrace
                                       timeout) leaves the reading the Status holds
tool-tip sensor       the tick before  the sample the next log row shows (the lead sensor's
                      each log row     noise model, its ``tool_tip``: trial_sensors.ToolTipSensor;
                                       the truth -- its ``truth`` -- gives the seam progress)
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
seam lost; a Reis command out of reach; a runaway; ``fault``: the Reis or the
GMF1 Status shows a fault it cannot move with -- the tracking cycle's rule,
droid.tasks.seam.cycle.arm_faults, asked before every cycle as droid-seamtrack
asks it; the detail names the arm and its faults) or as ``timeout`` when the
tool stops making progress along the seam (a stall) or at a generous hard cap
(:class:`ProgressLimit`; the stop detail says which rule fired).
"""
from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from droid.cli import BadInput
from droid.kinematics.transforms import inv_homo
from droid.experiments import phases, seam_kernel
from droid.sim.trial_cell import TrialGeometry, resolve_trial_cell, trial_geometry
from droid.sim.lockstep import ORDER_DEVICE, ORDER_TASK, ORDER_WORLD, Scheduler
from droid.tasks.seam.params import (DEAD_ZONE_CYCLES, LOST_CYCLES, MODE_LISTING, MODE_THESIS, MODES, SeamParams,
                                     speed_problem)
from droid.tasks.seam.cycle import TrackingCycle, stamped
from droid.tasks.seam.station import ArmStatus, SeamtrackStation
from droid.tasks.seam.delay import INVALID_READING, Reading
from droid.tasks.seam.report import COLUMNS, SETTLE_EXTRA_MM, log_row  # noqa: F401 (columns; settling)

ARM_MODELS = ("fast", "full")
#: The lead sensor models a trial may name: ``camera`` (the sensor's twin renders the frames its
#: station reads) or ``ideal`` (the exact geometry with the camera chain's noise); the layout's
#: sensor's package makes them (droid.sim.trial_cell.TrialCell.lead_sensor).
SENSOR_MODELS = ("camera", "ideal")
HOLDER_MODELS = ("gmf1", "fixed")  # the GMF1 through its controller and encoders, or an exact pose
from droid.brain.cell.device import HEARTBEAT_HZ  # [Hz], the droid-heartbeat declaration
CYCLE_TICKS = 2  # one 30 Hz seam-tracking cycle = 2 heartbeat ticks (cart_time_count; TrackingCycle.cycle_ticks)
LOG_TICKS = 6  # 10 Hz log (TrackingCycle.log_ticks)
#: The stall rule's window [s of simulated time] (ProgressLimit).
STALL_WINDOW_S = 30.0
#: The stall rule's least progress along the seam within one window [mm of seam coordinate s].
STALL_MIN_MM = 2.0
#: ... but never more than this fraction of what the commanded speed covers in a window.
STALL_MIN_FRACTION = 0.05
#: The hard cap: this many times run length / commanded speed [s], + HARD_CAP_EXTRA_S.
HARD_CAP_FACTOR = 12.0
HARD_CAP_EXTRA_S = 60.0


@dataclass(frozen=True)
class ProgressLimit:
    """When a trial that the tracking core has not ended ends as ``timeout``: a limit on progress.

    The trial's limit used to be 3 x run length / commanded speed + 30 s; on the full arm the
    thesis-mode tool advances at only 12-38 % of the commanded speed (the joints stick and
    slip under Coulomb friction; docs/experiments.md), so that limit ended most slow-but-
    tracking trials.  Now two rules, either of which ends the trial as ``timeout``:

    * **stall**: the tool's seam coordinate s (the truth's, the tool-tip sensor's ``truth``) has
      advanced less than ``min_progress_mm(speed)`` = min(``min_mm``, ``min_fraction`` x
      speed x ``window_s``) over the last ``window_s`` seconds of simulated time.  30 s and
      2 mm: the slowest progress of a tracking trial measured on the full arm is the thesis-mode
      tool at 4 mm/s commanded, 1.4-1.5 mm/s on average, i.e. ~42 mm a window -- 20x the 2 mm
      (0.66-0.71 mm/s, ~20 mm a window, if the seam patch were long enough not to pull it:
      docs/experiments.md on MAX_QUEUE);
      its stick-slip staircase pauses for about a second (a 150 mm run on (i) at 4 mm/s, seed
      1, 2026-11-25: the least progress over any 1 s was 0.14 mm, over any 2 s 0.9 mm, over any
      30 s 26 mm; over the whole chapter-6 matrix of that day, 78 trials that did not stall, the
      least progress over any 30 s was 24.7 mm, trial 1.6), so 30 s is a long multiple of any
      pause and of the depth oscillation's period (0.1-0.2 s), while a real stall (the arm
      stopped, the tool pushing against a limit, a tracker that holds its target) costs at most
      30 s of simulation instead of the whole cap.  The fraction (5 % of the commanded speed's
      distance in a window) keeps the rule from ending a trial commanded below ~1.3 mm/s whose
      tool follows at its usual fraction of the speed.
    * **hard cap** (a safety net): ``cap_factor`` x length / speed + ``cap_extra_s`` seconds:
      12x + 60 s lets a tool that follows at 1/12 (8 %) of the commanded speed finish (the
      slowest measured is 12 %: the 16 mm/s ramps of the 2026-11-25 matrix, 1.9 mm/s), and bounds a trial that creeps on forever (e.g. a 700 mm run at
      4 mm/s: 2160 s).
    """

    window_s: float = STALL_WINDOW_S
    min_mm: float = STALL_MIN_MM
    min_fraction: float = STALL_MIN_FRACTION
    cap_factor: float = HARD_CAP_FACTOR
    cap_extra_s: float = HARD_CAP_EXTRA_S

    def cap_s(self, length_mm: float, speed_mm_s: float) -> float:
        """The hard cap [s of simulated time] of a run of ``length_mm`` at ``speed_mm_s``."""
        return self.cap_factor * length_mm / speed_mm_s + self.cap_extra_s

    def min_progress_mm(self, speed_mm_s: float) -> float:
        """The least progress along the seam [mm] a window must show at this commanded speed."""
        return min(self.min_mm, self.min_fraction * speed_mm_s * self.window_s)

    def watch(self, length_mm: float, speed_mm_s: float) -> "ProgressWatch":
        return ProgressWatch(self, length_mm, speed_mm_s)


class ProgressWatch:
    """The progress of one trial against its :class:`ProgressLimit`: :meth:`check` it with the
    trial time and the tool's seam coordinate; it returns the ``timeout`` detail when a rule fires."""

    def __init__(self, limit: ProgressLimit, length_mm: float, speed_mm_s: float) -> None:
        self.limit = limit
        self.cap_s = limit.cap_s(length_mm, speed_mm_s)
        self.min_mm = limit.min_progress_mm(speed_mm_s)
        self._cap_text = (f"{limit.cap_factor:g} x {length_mm:g} mm / {speed_mm_s:g} mm/s "
                          f"+ {limit.cap_extra_s:g} s")
        self.samples: deque = deque()  # (t [s], s [mm]) over the last window and one before it
        self.last_s = math.nan  # the last seam coordinate seen [mm] (carried over missing readings)

    def check(self, t_s: float, s_mm: float | None) -> str | None:
        """One sample: ``t_s`` [s] since the trial's start, ``s_mm`` the tool's seam coordinate
        [mm] (None/NaN: no reading -- the last one counts).  None, or why the trial times out."""
        if s_mm is not None and math.isfinite(s_mm):
            self.last_s = float(s_mm)
        s = self.last_s
        if t_s >= self.cap_s:
            return f"hard cap: no end within {self.cap_s:.0f} s ({self._cap_text}), s {s:.1f} mm"
        w = self.limit.window_s
        self.samples.append((t_s, s))
        while len(self.samples) > 1 and self.samples[1][0] <= t_s - w:
            self.samples.popleft()  # keep the newest sample at or before t - window
        t0, s0 = self.samples[0]
        if t0 > t_s - w:
            return None  # not one whole window yet
        if math.isnan(s):
            d = 0.0  # no reading of the seam at all
        elif math.isnan(s0):
            return None  # the seam was found within the window
        else:
            d = s - s0
        if d < self.min_mm:
            return (f"stall: s advanced {d:.2f} mm in the last {t_s - t0:.0f} s (< {self.min_mm:g} mm), "
                    f"at s {s:.1f} mm, t {t_s:.0f} s")
        return None


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
    noise: object = None  # the lead sensor's noise (its package's kind); None: its default (the trials')
    dead_zone_cycles: int = DEAD_ZONE_CYCLES
    lost_cycles: int = LOST_CYCLES
    fast_params: object = None  # the fast arm model's parameters (its package's type); None: its defaults
    title: str = ""
    panels: str = "errors"  # "errors" (Figs 6.5-6.13) or "angles" (Figs 6.17-6.35: yaw/pitch panels)
    mode: str = MODE_THESIS  # tracking mode: thesis, listing, plus (docs/seamtrack.md)
    holder_mm_s: tuple = (0.0, 0.0, 0.0)  # the GMF1 wrist centre drifting at this global velocity [mm/s]
    latency_cycles: int = 0  # constant extra latency of every lead reading [30 Hz cycles] (stamped)
    holder: str = "gmf1"  # the workpiece holder: gmf1 (its controller and encoder path) or fixed
    tool_noise: bool = True  # the tool-tip sensor through the lead sensor's noise model (False: exact)
    cell: str | None = None  # a cell file: its layout, welder and holder (droid.sim.trial_cell);
    # None: the bundled layout, the Reis and the built-in cell's GMF1

    def __post_init__(self) -> None:
        if self.holder not in HOLDER_MODELS:
            raise BadInput(f"unknown holder model {self.holder!r} (known: {', '.join(HOLDER_MODELS)})")
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
        why = speed_problem(self.speed_mm_s)
        if why:
            raise BadInput(f"trial {self.trial_id}: {why}")
        if len(self.holder_mm_s) != 3 or not all(math.isfinite(v) for v in self.holder_mm_s):
            raise BadInput(f"trial {self.trial_id}: holder_mm_s must be 3 finite numbers [mm/s]")
        if not isinstance(self.latency_cycles, int) or self.latency_cycles < 0:
            raise BadInput(f"trial {self.trial_id}: latency_cycles must be an integer >= 0")
        if self.cell is not None and not (isinstance(self.cell, str) and self.cell):
            raise BadInput(f"trial {self.trial_id}: cell must be a cell file's path, got {self.cell!r}")


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
    holder_moved_mm: float = 0.0  # how far the holder's wrist centre moved during the trial (its Status) [mm]
    tool_seam_mm: list = field(default_factory=list)  # tool-tip readings placed at their capture (the
    # tracking cycle's place_tool): the measured seam points in the workpiece frame W [mm], one a log row
    tool_dropped: int = 0  # tool-tip readings whose capture instant lay outside the pose history

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


def run_trial(cfg: TrialConfig, layout=None, record: str | None = None,
              limit: ProgressLimit = ProgressLimit()) -> TrialResult:
    """Run one trial in lockstep and return its log (see the module docstring); ``record``: also
    write an MCAP recording of it there (droid.observe.lockstep, docs/observe.md); ``limit``: when
    a trial the core has not ended times out (:class:`ProgressLimit`).

    The config is read here, once (thesis §6.1): the trial's cell, resolved and checked
    (droid.sim.trial_cell.resolve_trial_cell; ``layout`` instead of its own), the geometry of the position,
    workpiece and wrist, the tracking core's parameters; from those values the welder and the
    holder are built on the cell, then the tracking cycle, the two sensors and the recorder;
    :class:`_LockstepTrial` runs the loop."""
    wall0 = time.perf_counter()
    tc = resolve_trial_cell(cfg.cell, cfg.arm, cfg.holder, layout)
    geo = trial_geometry(cfg.position, cfg.workpiece, cfg.wrist, tc.layout)
    params = SeamParams(speed_mm_s=cfg.speed_mm_s, yaw_gain=cfg.yaw_gain, pitch_gain=cfg.pitch_gain,
                        dead_zone_cycles=cfg.dead_zone_cycles, lost_cycles=cfg.lost_cycles,
                        length_mm=cfg.length_mm if cfg.length_mm is not None else default_length_mm(geo),
                        delay_cycles=cfg.delay_cycles, delay_at_mm=cfg.delay_at_mm,
                        mode=cfg.mode, compliance=cfg.arm == "full")  # the fast arm's drives are rigid
    sched = Scheduler(HEARTBEAT_HZ)
    arm, holder = tc.build_arms(sched, geo, cfg.arm, cfg.seed, cfg.fast_params, phases.mark)
    cyc = _tracking_cycle(params, geo, cfg.trial_id)
    lead = tc.lead_sensor(cfg.sensor)(geo.workpiece, cfg.sensor, cfg.noise, seed=cfg.seed,
                                      frames_per_read=cyc.cycle_ticks)
    tool_sensor = lead.tool_tip(cfg.tool_noise, seed=cfg.seed)
    recorder = _recorder(record, cfg.trial_id, geo) if record is not None else None
    trial = _LockstepTrial(sched, geo, arm, holder, cyc, (lead, tool_sensor), recorder,
                           latency_cycles=cfg.latency_cycles, holder_mm_s=cfg.holder_mm_s)
    phases.mark("ready", sched)
    trial.run(limit)
    phases.mark("tracked", sched)
    result = trial.finish()
    result.config = cfg
    result.wall_s = time.perf_counter() - wall0
    return result


def _recorder(record: str, trial_id: str, geo: TrialGeometry):
    """The MCAP recorder of the trial (droid.observe.lockstep, docs/observe.md) into file ``record``."""
    from droid.observe.lockstep import TrialRecorder
    from droid.sim.workpiece_mesh import workpiece_mesh

    lay, mesh = geo.layout, workpiece_mesh(geo.workpiece)
    return TrialRecorder(record, trial_id, geo.tool, geo.holder, geo.wrist.T_wcp_tool, geo.wrist.T_wcp_sensor,
                         geo.T_hold6_W, geo.q_hold_deg, geo.T_global_hold6, workpiece_mesh=mesh,
                         names=(lay.tool_robot, lay.holder_robot, lay.sensor, "tool"))


class _LockstepTrial:
    """One trial's loop on a 60 Hz scheduler (the module docstring's table): the welder and the
    holder, the lead and tool-tip sensors, the tracking station on ``cyc``, and the tick callbacks
    that join them -- arm, then sensors, then the task within each tick.  It is handed what
    run_trial made of the config: ``geo``, the geometry; ``holder``, None for a fixed one;
    ``sensors``, the lead and the tool-tip sensor; ``recorder``, or None; the lead readings'
    extra latency [30 Hz cycles] and the holder's drift [mm/s]; the run length and the speed
    are the tracking core's (``cyc.params``)."""

    def __init__(self, sched: Scheduler, geo: TrialGeometry, arm, holder, cyc: TrackingCycle, sensors: tuple,
                 recorder, *, latency_cycles: int, holder_mm_s) -> None:
        self.sched, self.geo, self.arm, self.holder, self.cyc, self.recorder = sched, geo, arm, holder, cyc, recorder
        self.lead, self.tool_sensor = sensors
        self.L = geo.camera_to_tcp_mm
        self.length, self.speed_mm_s = cyc.params.length_mm, cyc.params.speed_mm_s
        self.latency_cycles = latency_cycles
        self.result = TrialResult(None, camera_to_tcp_mm=self.L)  # its config: run_trial's
        self.T_hold0 = geo.T_global_hold6
        self.v_hold = np.asarray(holder_mm_s, float)
        self.moving_holder = bool(np.any(self.v_hold != 0.0))
        self.T_wcp_sensor, self.T_wcp_tool = geo.wrist.T_wcp_sensor, geo.wrist.T_wcp_tool
        self.T_W_hold6 = inv_homo(geo.T_hold6_W)  # the holder's wrist-centre frame -> the workpiece frame W
        self.t0_tick = sched.tick
        self.ct, self.lt = cyc.cycle_ticks, cyc.log_ticks
        self.state = {"lead": INVALID_READING, "lead_tick": 0, "tool": None, "tool_tick": 0, "out": None,
                      "done": False, "T_hold": self.T_hold0, "T_W_g": inv_homo(self.T_hold0 @ geo.T_hold6_W)}
        self.in_flight: deque = deque()  # (reading, Status tick) of the constant extra latency
        self.station = SeamtrackStation(cyc, HEARTBEAT_HZ, first_cycle_tick=self.t0_tick + self.ct,
                                        first_log_tick=self.t0_tick + 1)
        self.t_start = sched.t_ns / 1e9
        self.T_hold_start = self.T_hold0

    def hold_at(self, k: int) -> None:
        """The holder's pose at trial tick k: the GMF1's Status pose (the tracker's) and its true
        pose (the sensors'); a fixed holder drifts at ``holder_mm_s``."""
        state, holder = self.state, self.holder
        if holder is not None:
            state["T_hold"] = holder.status_pose()
            T_true = holder.true_wcp()
            if T_true is not state.get("T_true"):
                state["T_true"], state["T_W_g"] = T_true, inv_homo(T_true @ self.geo.T_hold6_W)
        elif self.moving_holder:
            T = self.T_hold0.copy()
            T[:3, 3] += self.v_hold * (k / HEARTBEAT_HZ)
            state["T_hold"], state["T_W_g"] = T, inv_homo(T @ self.geo.T_hold6_W)

    def s_of(self, m) -> float:
        return m.s_mm + self.L  # seam progress of the tool: 0 at the start (tool at s = -CAMERA_TO_TCP)

    def tool_s_now(self) -> float:
        """The tool's seam progress now, from the truth [mm]; NaN off the seam."""
        m = self.tool_sensor.truth(self.state["T_W_g"] @ self.arm.true_wcp() @ self.T_wcp_tool)
        return self.s_of(m) if m is not None else math.nan

    def sensors(self, tick: int) -> None:
        """The lead frame the next cycle reads, held back ``latency_cycles``; the tool-tip sample
        the next log row shows."""
        state, in_flight, ct, lt = self.state, self.in_flight, self.ct, self.lt
        k = tick - self.t0_tick
        self.hold_at(k)
        T_W_g = state["T_W_g"]
        if k % ct == ct - 1:  # the frame the next cycle reads (it reaches the Status next tick)
            T_true = self.arm.true_wcp()
            line = self.lead.read(T_W_g @ T_true @ self.T_wcp_sensor)
            if line is None:  # no line from this frame: the Status keeps the reading it holds
                in_flight.append(in_flight[-1] if in_flight else (state["lead"], state["lead_tick"]))
            else:
                r = _reading(line)
                if r.valid:
                    r = stamped(r, float(tick))  # the MVS world's frame stamp: its capture tick
                in_flight.append((r, tick + 1))
            while len(in_flight) > self.latency_cycles:
                state["lead"], state["lead_tick"] = in_flight.popleft()
        if k % lt == lt - 1:
            state["tool"] = self.tool_sensor.read(T_W_g @ self.arm.true_wcp() @ self.T_wcp_tool)
            state["tool_tick"] = tick  # its capture stamp

    def lead_now(self):
        return self.state["lead"], self.state["lead_tick"]

    def task(self, tick: int) -> None:
        """The tracking station's tick, as droid-seamtrack's: its commands to the arms, its log row."""
        state, arm, holder = self.state, self.arm, self.holder
        if self.recorder is not None:
            self.recorder.sample(tick, self.sched.t_ns, arm, state)
        if state["done"]:
            return
        tool = ArmStatus(arm.name, tick, arm.status_pose(), arm.status_fault(), joints_deg=arm.status_joints)
        hold = ArmStatus(holder.name if holder is not None else "holder", tick, state["T_hold"],
                         holder.status_fault() if holder is not None else None)  # a fixed holder: no faults
        res = self.station.on_tick(tick, tool, hold, self.lead_now)
        state["out"] = self.station.out
        if res.stop is not None:
            state["done"] = True
            result = self.result
            result.stop_reason, result.stop_detail = res.stop.reason, res.stop.detail
            result.stop_s_mm = self.tool_s_now()
            result.stop_t_s = (self.sched.t_ns / 1e9)
            return
        if res.tool_cmd is not None:
            arm.command_cart(res.tool_cmd, self.ct)
        if res.hold_cmd is not None and holder is not None and not self.moving_holder:
            holder.hold(res.hold_cmd, self.ct / HEARTBEAT_HZ)  # gen_hold_robot_wcp, as droid-seamtrack
        if res.log:
            self.log_row(tick)

    def log_row(self, tick: int) -> None:
        """One 10 Hz log row, and the tool-tip reading placed with the poses of its capture."""
        state, result = self.state, self.result
        tool = state["tool"]
        if tool is not None:  # placed with the poses of its capture, as droid-seamtrack's log does
            placed = self.cyc.place_tool(Reading(tool.height_mm, tool.lateral_mm, tool.roll_rad, True,
                                                 stamp_tick=float(state["tool_tick"])), tick, self.T_wcp_tool)
            if placed is not None:
                result.tool_seam_mm.append((self.T_W_hold6 @ np.append(placed.seam_in_hold_mm, 1.0))[:3])
        result.rows.append(_row(self.sched.t_ns / 1e9 - self.t_start, state["lead"], state["tool"], state["out"],
                                self.L, self.s_of))

    def run(self, limit: ProgressLimit) -> None:
        """Start the holder, wire the tick callbacks, and run until the core stops or ``limit``
        (checked once a simulated second) ends the trial as ``timeout``."""
        sched, state, arm, holder, result = self.sched, self.state, self.arm, self.holder, self.result
        watch = limit.watch(self.length, self.speed_mm_s)
        if holder is not None:
            self.hold_at(0)
            self.T_hold_start = state["T_hold"]
            if self.moving_holder:  # one slow cartesian MOVE through KAREL, lasting past the hard cap
                holder.drift(self.v_hold, watch.cap_s + 1.0)
        sched.on_tick(lambda tick: arm.tick(), "arm", order=ORDER_WORLD)
        sched.on_tick(self.sensors, "sensors", order=ORDER_DEVICE)
        sched.on_tick(self.task, "seamtrack", order=ORDER_TASK)
        while not state["done"]:
            sched.run_ticks(60)  # 1 s of simulated time, then the progress check
            if state["done"]:
                break
            s_now = self.tool_s_now()
            why = watch.check(sched.t_ns / 1e9 - self.t_start, s_now)
            if why is not None:
                result.stop_reason, result.stop_detail = "timeout", why
                result.stop_t_s = sched.t_ns / 1e9
                result.stop_s_mm = s_now
                break

    def finish(self) -> TrialResult:
        """The result's times, frame counts and holder travel; the recording closed."""
        result, holder = self.result, self.holder
        t_start = self.t_start
        result.stop_t_s -= t_start
        result.sim_s = self.sched.t_ns / 1e9 - t_start
        result.prep_s = t_start
        result.frames, result.valid_frames = self.lead.frames, self.lead.valid
        result.dropped = self.cyc.dropped
        result.tool_dropped = self.cyc.tool_dropped
        if holder is not None:
            result.holder_moved_mm = float(np.linalg.norm(holder.status_pose()[:3, 3] - self.T_hold_start[:3, 3]))
        elif self.moving_holder:
            result.holder_moved_mm = float(np.linalg.norm(self.v_hold) * result.sim_s)
        if self.recorder is not None:
            self.recorder.close()
        return result


def _tracking_cycle(params: SeamParams, geo: TrialGeometry, trial_id: str) -> TrackingCycle:
    """The tracking cycle of ``params`` (BadInput naming the trial when they do not fit)."""
    try:
        cyc = TrackingCycle(params, geo.wrist.T_wcp_tool, geo.wrist.T_wcp_sensor, geo.tool,
                            heartbeat_hz=HEARTBEAT_HZ)
    except ValueError as exc:
        raise BadInput(f"trial {trial_id}: {exc}") from None
    if params.mode != MODE_LISTING:  # the patch search of interpolate_thesis, compiled (the same bits)
        seam_kernel.use_on(cyc.core)
    seam_kernel.use_on_cycle(cyc)  # the pose histories' interpolation, compiled (the same bits)
    return cyc


def _reading(line) -> Reading:
    """The tracker's reading of the lead sensor's parsed line (droid.brain.plumbing.sensor_line: a
    LineReading, or Garbled), as the Brain's Status hands it on: invalid for ``invalid`` and for
    a garbled line."""
    return Reading(line.x_mm, line.y_mm, line.roll_rad, True) if line.valid else INVALID_READING


def _row(t_s: float, lead: Reading, tool, out, L: float, s_of) -> tuple:
    """The 10 Hz log row: ``s_mm`` from the tool-tip sensor's seam coordinate (the truth)."""
    t = None if tool is None else (tool.lateral_mm, tool.height_mm, tool.roll_rad)
    return log_row(s_mm=s_of(tool) if tool is not None else math.nan, t_s=t_s, lead=lead, tool=t, out=out,
                   camera_to_tcp_mm=L)


def with_overrides(cfg: TrialConfig, **kw) -> TrialConfig:
    return replace(cfg, **kw)
