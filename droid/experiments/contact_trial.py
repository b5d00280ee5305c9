"""A lockstep trial of the force task (issue 27 item 5; thesis §7.3, force control as the next
sensor task): the full Reis arm pressing on and sliding along the step workpiece's flat face,
held at a normal force (docs/contact.md).

The workpiece sits where the seam layout's position (i) puts it (on a fixed fixture: the
holder is not simulated here), its surfaces push on the tool point through the contact model
of its ``[contact]`` table (droid.sim.contact); the arm is every core of the Reis subunit
(droid.sim.reis.cell.LockstepArm, the layout's tool robot of the built-in cell built by its lockstep
builder, homed from a seeded power-up pose); the wrist F/T sensor
is the Net F/T twin read by droid-ft's core (droid.sim.ft.lockstep), biased before the
approach (the tool's weight taken out); the task is droid.tasks.contact.core.ContactStation.

The tool starts ``clearance_mm`` above the lower plate, ``lateral_mm`` beside the seam
(the lower plate is the step's right side), tool axis along -z_W, travel along +x_W.

Rows (``COLUMNS``), one per controller cycle: time, phase, the normal force (the
sensor's) and its error, the true contact force, the tool point's true depth below the
surface and its travel, its speed along the path.  :func:`summarize` takes the trial's
figures from them (:class:`ContactSummary`: the force error's RMS and max over the path after
``settle_after_s``, the peak force, the mean speed, ...), :func:`summary_line` gives the line
``normal force RMS error X N, max Y N ...``.  droid-experiment runs the trial as a plan's
(``trial = "contact"``: droid.experiments.contact_plan, contact_report).
"""
from __future__ import annotations

import csv
import math
from dataclasses import asdict, dataclass

import numpy as np

from droid.experiments import phases
from droid.sim.trial_cell import trial_geometry
from droid.kinematics.transforms import inv_homo, trans
from droid.sim.contact import ToolContact
from droid.sim.ft.lockstep import LockstepFt
from droid.sim.lockstep import ORDER_TASK, Scheduler
from droid.tasks.contact.core import ArmStatus, ContactStation, FtStatus, load_gains
from droid.brain.cell.cell_layout import T_W_SEAM

COLUMNS = ("t_s", "phase", "force_n", "force_error_n", "true_force_n", "friction_n", "depth_mm", "along_mm",
           "speed_mm_s")
HEARTBEAT_HZ = 60.0
#: T_wcp_sensor and T_sensor_tool as cells/sim.toml's F/T twin: the sensor 100 mm out, the tool point 150 mm beyond
FT_POSE_MM = (0.0, 0.0, 100.0)


# Alike in shape only to other numeric dataclasses (the contact Gains): a trial's settings, not gains.
@dataclass(frozen=True)
class ContactTrialConfig:
    """One trial (defaults: the issue's measure: 20 N at 10 mm/s over 200 mm)."""

    force_n: float = 20.0
    speed_mm_s: float = 10.0
    length_mm: float = 200.0
    seed: int = 1
    workpiece: str = "step_input"
    position: str = "i"
    lateral_mm: float = -25.0  # the tool's path beside the seam (the lower plate) [mm]
    x_start_mm: float = 0.0  # along the seam, in W [mm]
    clearance_mm: float = 5.0  # above the surface at the start [mm]
    gains: str | None = None  # a gains file (default: the bundled one)
    settle_after_s: float = 1.0  # the summary starts this long after the path starts [s]
    max_s: float = 60.0


@dataclass
class ContactResult:
    rows: list
    stop: str
    detail: str
    summary: str  # summary_line(figures)
    rms_n: float
    max_n: float
    figures: ContactSummary | None = None
    sim_s: float = math.nan  # simulated time of the whole trial (homing, approach, path) [s]


def run_contact_trial(cfg: ContactTrialConfig) -> ContactResult:
    geo = trial_geometry(cfg.position, cfg.workpiece)
    wp = geo.workpiece
    T_wcp_tool = geo.wrist.T_wcp_tool
    gains = load_gains(cfg.gains, HEARTBEAT_HZ)

    def wcp_for(x_w: float, z_w: float) -> np.ndarray:
        return geo.T_global_W @ trans(x_w, cfg.lateral_mm, z_w) @ T_W_SEAM @ inv_homo(T_wcp_tool)

    T_start = wcp_for(cfg.x_start_mm, cfg.clearance_mm)
    q_start = geo.tool.ik(T_start, np.zeros(6))
    sched = Scheduler(HEARTBEAT_HZ)
    arm = _tool_robot(sched, geo.layout.tool_robot, cfg.seed)
    phases.mark("built", sched)
    if not arm.home(60.0):
        raise RuntimeError("homing did not finish")
    phases.mark("homed", sched)
    counts = np.rint(geo.tool.gearing.joints_to_counts(q_start)).astype(np.int32)
    cmd = arm.command_joint(counts, arm.ticks_for(4.0))
    if not arm.move_done(cmd, 9.0):
        raise RuntimeError("the move to the start did not finish")
    sched.run_for(1.0)
    phases.mark("approached", sched)
    contact = ToolContact(wp, geo.T_global_W, geo.tool.base, T_wcp_tool)
    arm.attach_contact(contact)
    T_wcp_sensor = trans(*FT_POSE_MM)
    ft = LockstepFt(sched, arm, T_wcp_sensor, inv_homo(T_wcp_sensor) @ T_wcp_tool, seed=cfg.seed + 7)
    sched.run_for(0.2)
    ft.bias()
    sched.run_for(0.2)
    station = ContactStation(gains, HEARTBEAT_HZ, T_wcp_tool, cfg.force_n, cfg.speed_mm_s, cfg.length_mm)
    rows: list = []
    state = {"t0": None}
    R_W = geo.T_global_W[:3, :3]

    def task(tick: int) -> None:
        a = ArmStatus.of_record(arm.status)  # the fault bits droid-contact stops on (FAULTS_STOP_RUN)
        f = ft.fields
        fs = FtStatus(np.asarray(f["force_tool_N"], float), bool(f["valid"]), bool(f["stale"]))
        out = station.on_tick(tick, a, fs)
        if out.cmd is not None:
            arm.command_cart(out.cmd, out.ticks)
        if out.cycle:
            t = sched.t_ns / 1e9
            if state["t0"] is None:
                state["t0"] = t
            tool_W = R_W.T @ (contact.tool_mm - geo.T_global_W[:3, 3])
            v_W = R_W.T @ contact.tool_v_mm_s
            f_W = R_W.T @ contact.force_N  # the true contact force in W: z the normal, x-y friction
            rows.append((t - state["t0"], station.phase, fs.normal_n, cfg.force_n - fs.normal_n, float(f_W[2]),
                         float(math.hypot(f_W[0], f_W[1])), -float(tool_W[2]), float(tool_W[0]) - cfg.x_start_mm,
                         float(v_W[0])))

    sched.on_tick(task, "contact.task", order=ORDER_TASK)
    phases.mark("ready", sched)
    arm.run_until(lambda: station.done is not None, cfg.max_s)
    phases.mark("tracked", sched)
    stop = station.done or "timeout"
    su = summarize(rows, cfg, stop, station.detail)
    return ContactResult(rows, stop, station.detail, summary_line(su), su.rms_n, su.max_n, su, sched.t_ns / 1e9)


def _tool_robot(sched: Scheduler, name: str, seed: int):
    """The layout's tool robot ``name`` of the built-in cell, built on ``sched`` by its package's
    lockstep builder (droid.sim.lockstep_cell.build_lockstep_cell) with the trial's ``seed``, the
    cell file's default ``stale_ticks`` and no world device of the cell's (the trial brings its own
    workpiece contact): the Reis's :class:`~droid.sim.reis.cell.LockstepArm`, whose plant the
    contact pushes on (``attach_contact``) and whose wrench the F/T twin reads."""
    from droid.sim.trial_cell import builtin_cell
    from droid.sim.lockstep_cell import build_lockstep_cell

    return build_lockstep_cell(builtin_cell(), seed, world={}, sched=sched, subunits={name: None}).subunits[name].parts


@dataclass(frozen=True)
class ContactSummary:
    """How well one trial held the force (thesis §7.3's force control; N, mm, mm/s; NaN where no
    row qualifies).  "After settling": path rows from ``settle_after_s`` after the path started."""

    trial_id: str
    force_n: float  # the set force [N]
    speed_mm_s: float  # the commanded speed along the path [mm/s]
    length_mm: float  # the commanded path [mm]
    seed: int
    settle_after_s: float
    cycles: int  # controller cycles logged (every row)
    settled_cycles: int  # path cycles after settling (the RMS's samples)
    rms_n: float  # RMS of the sensor's force error after settling [N]
    max_n: float  # largest |force error| after settling [N]
    max_path_n: float  # largest |force error| over the whole path [N]
    peak_force_n: float  # largest sensor normal force after touch (settle and path) [N]
    mean_speed_mm_s: float  # mean true speed along the path after settling [mm/s]
    mean_true_force_n: float  # the contact model's mean normal force after settling [N]
    min_true_force_n: float  # its smallest over the whole path (0: the tool left the surface) [N]
    mean_friction_n: float  # the mean friction force after settling [N]
    path_mm: float  # the true tool point's travel at the last row [mm]
    stop: str  # the task's stop reason (droid.tasks.contact.core), or "timeout"
    stop_detail: str

    def as_dict(self) -> dict:
        return asdict(self)


def summarize(rows: list, cfg: ContactTrialConfig, stop: str, detail: str, trial_id: str = "") -> ContactSummary:
    """The trial's figures from its rows (``COLUMNS``; :class:`ContactSummary`)."""
    path = [r for r in rows if r[1] == "path"]
    t_from = (path[0][0] + cfg.settle_after_s) if path else math.inf
    late = [r for r in path if r[0] >= t_from]

    def col(rs, i) -> np.ndarray:
        return np.array([r[i] for r in rs], float)

    def stat(fn, v) -> float:
        return float(fn(v)) if len(v) else math.nan

    errs = col(late, 3)
    touched = col([r for r in rows if r[1] in ("settle", "path")], 2)
    return ContactSummary(
        trial_id=trial_id, force_n=cfg.force_n, speed_mm_s=cfg.speed_mm_s, length_mm=cfg.length_mm, seed=cfg.seed,
        settle_after_s=cfg.settle_after_s, cycles=len(rows), settled_cycles=len(late),
        rms_n=stat(lambda e: np.sqrt(np.mean(e ** 2)), errs), max_n=stat(lambda e: np.max(np.abs(e)), errs),
        max_path_n=stat(lambda e: np.max(np.abs(e)), col(path, 3)), peak_force_n=stat(np.max, touched),
        mean_speed_mm_s=stat(np.mean, col(late, 8)), mean_true_force_n=stat(np.mean, col(late, 4)),
        min_true_force_n=stat(np.min, col(path, 4)), mean_friction_n=stat(np.mean, col(late, 5)),
        path_mm=float(rows[-1][7]) if rows else math.nan, stop=stop, stop_detail=detail)


def summary_line(su: ContactSummary) -> str:
    """One line: the force errors after settling, the speed and how the trial ended, units included."""
    head = f"{su.trial_id}: " if su.trial_id else ""
    return (f"{head}normal force RMS error {su.rms_n:.2f} N, max {su.max_n:.2f} N (path after "
            f"{su.settle_after_s:g} s settling, {su.settled_cycles} cycles); {su.force_n:g} N at "
            f"{su.speed_mm_s:g} mm/s over {su.length_mm:g} mm, mean speed {su.mean_speed_mm_s:.2f} mm/s; "
            f"seed {su.seed}; stop: {su.stop} ({su.stop_detail})")


def write_csv(path: str, rows: list) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([r[0], r[1], *(f"{x:.4f}" for x in r[2:])])


if __name__ == "__main__":
    import sys

    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 1
    res = run_contact_trial(ContactTrialConfig(seed=seed))
    if len(sys.argv) > 2:
        write_csv(sys.argv[2], res.rows)
    print(res.summary)
