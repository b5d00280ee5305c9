"""droid-seamtrack SPEED: dynamic seam tracking on the running cell (thesis §5.1-5.5, §6.1-6.2).

The shell of the seam-tracking task program (thesis §5.5, Figure 5.9).  The
core is :class:`droid.tasks.seam.core.SeamTracker` (the listing's functions,
eq. 5.1-5.11); this program does what the listing's ``main()`` loop does
around it, on the Brain's databases only (a task never touches a device, §3.4):

1. attach to the Status/Command records of the tool robot (the Reis, arm1),
   the workpiece holder (the GMF1) and the lead sensor (mvs), and -- for data
   collection, §6.1 -- the tool-tip sensor (tool);
2. with ``--start POSITION``: move the holder and then the tool robot to the
   start poses of that layout position (§6.1.2; droid/cells/seamtrack_layout.toml);
   a start move a protective stop cancelled (braking alone) is resumed from where the
   arm stopped, at most 3 times, a line on stderr each (BrainArm.move,
   droid.tasks.resume; ``--no-resume``: exit 1 instead), and the summary line ends with
   ``; start moves: 1 resume after a protective stop`` when there was any; SIGINT/SIGTERM
   during a start move stops it where the arm stands (exit 130);
3. every tick hand both robots' Status poses to the tracking cycle
   (droid.tasks.seam.cycle.TrackingCycle, the same code the lockstep trial
   runs); every ``heartbeat_hz / 30`` ticks (30 Hz) read the lead sensor's
   reading, step the cycle -- the core of ``--mode`` (thesis, listing, plus)
   -- and write the Reis cartesian command for the next cycle
   (``cart_time_count`` = one cycle of ticks); the GMF1 is told once to hold
   its pose (gen_hold_robot_wcp);
4. every ``heartbeat_hz / 10`` ticks (10 Hz, §6.1) append a CSV row (``--log FILE``);
5. stop cleanly -- no new command is written, so the Reis completes its last
   one-cycle step and stands -- at the end of the seam (``--length`` of tool
   travel reached), when the seam is lost, on an unreachable command, on a
   runaway, when the Reis or the GMF1 reports a fault it cannot move with
   (servo, watchdog, device) or a protective stop (braking, collision: the weld
   slowed or stopped where the arm braked) (``fault``, naming the arm and its faults, e.g.
   ``stopped: fault at 312.0 mm (arm1 faults: servo, braking)``; the rule is
   droid.tasks.seam.cycle's, shared with the lockstep trial), on a stale
   subunit, or on SIGINT/SIGTERM -- the tracking itself is never resumed (the start moves
   are); then print which, and a summary line (the
   ``--log`` and ``--figure`` are written whatever the stop).  An arm that
   shows such a fault before tracking starts is refused before anything
   moves (BrainArm.check_fresh: ``arm1 cannot move: fault watchdog ...``).

Exit codes: 0 end of seam; 130 interrupted (SIGINT/SIGTERM); 1 seam lost,
unreachable command, runaway, an arm fault (during the run or before it), a
subunit stale for 2 s, cell not up, heartbeat lost; 2 bad arguments or layout
(nothing moves).
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np

from droid.brain.db.databases import open_brain
from droid.brain.runtime.heartbeat import TickSubscriber
from droid.brain.db.layouts import NO_CAPTURE_AGE
from droid.brain.runtime.program import Stop, open_cell, parser  # noqa: F401 (Stop: tests patch seamtrack.Stop)
from droid.cli import (EXIT_OK, EXIT_RUNTIME, BadInput, RuntimeFailure, bounded_float,
                       bounded_int, run)
from droid.tasks.arm import BrainArm
from droid.tasks.guarded import refuse_colliding_move
from droid.tasks.resume import MAX_RESUMES, summary_note
from droid.tasks.seam import report
from droid.tasks.seam.params import (DEAD_ZONE_CYCLES, LOST_CYCLES, MAX_CYCLES, MAX_GAIN, MAX_RUN_LENGTH_MM,
                                     MAX_SPEED_MM_S, MODE_THESIS, MODES, SeamParams)
from droid.tasks.seam.stops import STOP_END
from droid.tasks.seam.cycle import SENSOR_LAG_TICKS, TrackingCycle  # noqa: F401 (SENSOR_LAG_TICKS: docs)
from droid.tasks.seam.station import ArmStatus, SeamtrackStation
from droid.tasks.seam.delay import INVALID_READING, Reading
from droid.kinematics.transforms import record_pose
from droid.brain.cell.cell_layout import POSITION_IDS, check_bases, layout_for_cell, layout_path_for
from droid.tasks.shell import TickLoop, check_output_dirs, ready_then_run, run_on_ticks, say_outcome

PROG = "droid-seamtrack"
START_MOVE_MIN_S = 3.0  # the shortest move to a start pose [s]
START_MOVE_MARGIN = 1.5  # move time = margin x the slowest joint at its speed limit
SETTLED_COUNTS = 2  # after a start move: encoder change per poll [counts] that counts as still
SETTLE_POLL_S = 0.1
SETTLE_TIMEOUT_S = 3.0
# Cycle counting, the pose histories and the latency compensation (a reading placed with the
# poses of its capture instant, SENSOR_LAG_TICKS) live in droid.tasks.seam.cycle, shared with
# the lockstep trial.


#: argparse types of the run's numbers: the limits live in droid.tasks.seam.params (issue 16).
speed_mm_s = bounded_float(0.0, MAX_SPEED_MM_S, "mm/s", lo_open=True)
gain = bounded_float(0.0, MAX_GAIN)
cycles = bounded_int(0, MAX_CYCLES, "cycles")
travel_mm = bounded_float(0.0, MAX_RUN_LENGTH_MM, "mm")
run_length_mm = bounded_float(0.0, MAX_RUN_LENGTH_MM, "mm", lo_open=True)


def build_parser():
    ap = parser(PROG, "Track a seam with the tool robot, steered by the lead sensor, at SPEED mm/s "
                      "(thesis §5.5); stops at the end of the seam, on seam loss or on Ctrl-C.")
    ap.add_argument("speed", type=speed_mm_s, metavar="SPEED", help="travel speed along the seam [mm/s]")
    ap.add_argument("--mode", choices=MODES, default=MODE_THESIS,
                    help="tracker: thesis (§5.2's patch, default), listing (the literal port of the "
                         "listing), plus (seam map, holds the speed; docs/seamtrack.md)")
    ap.add_argument("--yaw-gain", type=gain, default=0.15, metavar="K",
                    help="yaw angle gain k_yaw (eq. 5.6; default 0.15, §6.2.1)")
    ap.add_argument("--pitch-gain", type=gain, default=0.25, metavar="K",
                    help="pitch angle gain k_pitch (eq. 5.7; default 0.25)")
    ap.add_argument("--delay", type=cycles, default=0, metavar="CYCLES",
                    help="transport delay [30 Hz cycles] inserted once (§6.2.5; default 0 = none)")
    ap.add_argument("--delay-at", type=travel_mm, default=150.0, metavar="MM",
                    help="tool travel at which the transport delay starts [mm] (default 150)")
    ap.add_argument("--dead-zone", type=cycles, default=DEAD_ZONE_CYCLES, metavar="CYCLES",
                    help=f"cycles at the start before the sensor is read (default {DEAD_ZONE_CYCLES})")
    ap.add_argument("--lost-cycles", type=bounded_int(1, MAX_CYCLES, "cycles"), default=LOST_CYCLES, metavar="CYCLES",
                    help=f"consecutive invalid readings that count as seam lost (default {LOST_CYCLES})")
    ap.add_argument("--length", type=run_length_mm, default=None, metavar="MM",
                    help="run length: tool travel [mm] at which the seam ends (default: track until "
                         "the lead sensor loses the seam)")
    ap.add_argument("--start", choices=POSITION_IDS, default=None, metavar="POSITION",
                    help="first move both robots to this layout start position (i..vii, §6.1.2)")
    ap.add_argument("--layout", metavar="FILE", default=None,
                    help="seam-tracking layout (default: the cell file's [cell] layout, else the bundled "
                         "cells/seamtrack_layout.toml)")
    ap.add_argument("--wrist", default="standard", metavar="NAME",
                    help="wrist set-up of the layout (default standard; extension30: experiment 5)")
    ap.add_argument("--tool-sensor", default="tool", metavar="SUBUNIT",
                    help="tool-tip measuring sensor logged with the lead sensor ('none': no tool "
                         "columns; default tool)")
    ap.add_argument("--log", metavar="FILE", default=None, help="write the 10 Hz CSV log here")
    ap.add_argument("--figure", metavar="FILE", default=None,
                    help="draw the run's figure (PNG, thesis Figs 6.5-6.35) here at the end")
    ap.add_argument("--no-resume", action="store_true",
                    help="with --start: fail a start move a protective stop (braking) cancelled instead of "
                         f"resuming it from where the arm stopped (at most {MAX_RESUMES} times)")
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    ap.add_argument("--record", metavar="FILE", default=None,
                    help="record the cell by tick into this MCAP file (droid-record's layout, docs/observe.md)")
    return ap


def reading_of(rec, period_ns: int | None = None) -> Reading:
    """A lead-sensor Status record (Table 3.3) as a reading: x depth, y lateral [mm], roll from R.

    With ``period_ns`` (the heartbeat period) and a stamped line (``capture_age_us``, layout
    v2): the capture instant in heartbeat ticks, ``tick - age / period`` (issue 12)."""
    if int(rec["stale"]) or int(rec["homed"]):  # homed = 1: the reading is invalid (Table 3.3)
        return INVALID_READING
    R = rec["R"]
    stamp = None
    names = getattr(getattr(rec, "dtype", None), "names", None) or ()
    if period_ns and "capture_age_us" in names and int(rec["capture_age_us"]) != NO_CAPTURE_AGE:
        stamp = int(rec["tick"]) - int(rec["capture_age_us"]) * 1000.0 / period_ns
    return Reading(float(rec["x"]), float(rec["y"]), math.atan2(float(R[1][0]), float(R[0][0])), True,
                   stamp_tick=stamp)


def pose_of(rec) -> np.ndarray:
    """A Status record's wrist-centre pose as a 4x4 [mm] (global frame, Table 3.1)."""
    return record_pose(rec)


#: the holder's detour to a start pose whose straight move would sweep its workpiece through the
#: welder (docs/guard.md §9): the pose's joints 1-3 turned by these [deg] -- the base away from the
#: welder, the upper arm and forearm raised -- then the pose itself; checked like the straight move
DETOUR_DEG = np.array([-20.0, 20.0, 40.0, 0.0, 0.0, 0.0])


def start_move_s(arm: BrainArm, q_from_deg, q_to_deg) -> float:
    """A start move's time [s]: max(START_MOVE_MIN_S, START_MOVE_MARGIN x the slowest joint at its limit)."""
    dq = np.abs(np.asarray(q_to_deg, float) - np.asarray(q_from_deg, float))
    return max(START_MOVE_MIN_S, START_MOVE_MARGIN * float(np.max(dq / arm.model.vmax_deg_s)))


def start_route(cell, arm: BrainArm, q_now_deg, q_goal_deg, what: str) -> list[np.ndarray]:
    """The joint way-points [deg] of ``arm``'s move to a start pose, checked against the other arms'
    bodies where they stand (droid.tasks.guarded; a cell with a ``[guard]`` table): ``[q_goal]``
    when the straight joint move is clear, ``[q_goal + DETOUR_DEG, q_goal]`` when it is not and
    both legs of the detour are; BadInput with the guard's line when neither is (nothing moved).
    A cell without a ``[guard]`` table: ``[]`` (the Cartesian move, unchecked)."""
    if "guard" not in cell.raw:
        return []
    name = arm.sub.name
    q_now, q_goal = np.asarray(q_now_deg, float), np.asarray(q_goal_deg, float)
    try:
        refuse_colliding_move(cell, name, q_now, q_goal, start_move_s(arm, q_now, q_goal))
        return [q_goal]
    except BadInput as exc:
        straight = str(exc)
    via = q_goal + DETOUR_DEG
    try:
        arm.check_joint_target(np.round(arm.model.gearing.joints_to_counts(via)), 1e9, None)
        refuse_colliding_move(cell, name, q_now, via, start_move_s(arm, q_now, via))
        refuse_colliding_move(cell, name, via, q_goal, start_move_s(arm, via, q_goal))
    except BadInput:
        raise BadInput(f"{name} to the {what}: {straight} (and no detour is clear)") from None
    return [via, q_goal]


def move_to_start(arm: BrainArm, T: np.ndarray, what: str, quiet: bool, resume: bool = True, cell=None) -> int:
    """Move ``arm`` to the wrist-centre pose ``T`` (global, mm) and wait; the number of resumes after
    a protective stop it took (BrainArm.move; ``resume`` False: ``--no-resume``).  In a ``cell``
    with a ``[guard]`` table the move goes in joint space along :func:`start_route` (the path the
    guard's bodies were checked on), else as droid-move's Cartesian move.  Interrupted (SIGINT/SIGTERM,
    Stop): the move is stopped where the arm stands and droid.tasks.arm.Interrupted raised."""
    rec = arm.read()
    arm.check_fresh(rec)
    if not int(rec["homed"]):
        raise RuntimeFailure(f"{arm.sub.name} is not homed: run 'droid-home {arm.sub.name}' first")
    q_now = arm.joints_deg(rec)
    from droid.kinematics.transforms import T_to_pose

    pose = T_to_pose(T)
    _, q = arm.check_cart_target(pose, 1e9, q_now)
    route = start_route(cell, arm, q_now, q, what) if cell is not None else []
    resumes = 0

    def go(mode: str, target, seconds: float, label: str) -> int:
        if not quiet:
            print(f"{PROG}: moving {arm.sub.name} to the {label} ({seconds:.1f} s)", file=sys.stderr)
        return arm.move(mode, target, seconds, resume=resume, arrive=False, timeout=lambda s: 3 * s + 30.0,
                        interrupted=lambda: Stop.requested)

    if not route:
        resumes += go("cart", pose, start_move_s(arm, q_now, q), what)
    q_from = q_now
    for k, q_leg in enumerate(route):
        label = what if k == len(route) - 1 else f"way clear of the other arms to the {what}"
        counts = np.round(arm.model.gearing.joints_to_counts(q_leg))
        resumes += go("joint", counts, start_move_s(arm, q_from, q_leg), label)
        q_from = q_leg
    # "done" is the planner's; let the servo settle before tracking starts from here
    prev = None
    deadline = time.monotonic() + SETTLE_TIMEOUT_S
    while time.monotonic() < deadline:
        pos = np.asarray(arm.read()["encoder_pos"], np.int64)
        if prev is not None and np.max(np.abs(pos - prev)) <= SETTLED_COUNTS:
            break
        prev = pos
        time.sleep(SETTLE_POLL_S)
    return resumes


class Tracker:
    """The loop of the seamtrack program around the core (see the module docstring)."""

    def __init__(self, args, cell, layout) -> None:
        self.args = args
        self.cell = cell
        self.layout = layout
        try:
            self.params = SeamParams(
                speed_mm_s=args.speed, yaw_gain=args.yaw_gain, pitch_gain=args.pitch_gain,
                dead_zone_cycles=args.dead_zone, lost_cycles=args.lost_cycles,
                length_mm=args.length if args.length is not None else math.inf,
                delay_cycles=args.delay, delay_at_mm=args.delay_at, mode=args.mode)
        except ValueError as exc:
            raise BadInput(str(exc)) from None
        self.wrist = layout.wrist(args.wrist)
        check_bases(layout, cell)
        sensor = cell.subunit(layout.sensor)
        if sensor.is_arm:
            raise BadInput(f"layout sensor {sensor.name} is an arm, not a sensor")
        self.tool_sub = None
        if args.tool_sensor != "none":
            if args.tool_sensor in cell.subunits:
                self.tool_sub = cell.subunit(args.tool_sensor)
            elif args.tool_sensor != "tool":  # named explicitly: it must exist
                cell.subunit(args.tool_sensor)
        self.tool_robot = BrainArm(cell, layout.tool_robot)
        self.hold = BrainArm(cell, layout.holder_robot)
        self.sensor_sub = sensor
        try:
            self.cyc = TrackingCycle(self.params, self.wrist.T_wcp_tool, self.wrist.T_wcp_sensor, self.tool_robot.model,
                                     heartbeat_hz=cell.heartbeat_hz)
        except ValueError as exc:
            raise BadInput(f"cell {cell.name}: {exc}") from None
        self.core = self.cyc.core
        self.station = SeamtrackStation(self.cyc, cell.heartbeat_hz)
        self.log_due = False
        self.rows: list[tuple] = []
        self.t0 = None
        self.dbs = []
        self.recorder = None  # droid.observe.record.LiveRecorder with --record
        self.resumes = 0  # the start moves' resumes after a protective stop (BrainArm.move)

    # -- set-up ------------------------------------------------------------
    def connect(self) -> None:
        self.tool_robot.connect()
        self.hold.connect()
        self.lead_db = open_brain(self.cell, self.sensor_sub, "status")
        self.dbs.append(self.lead_db)
        self.tool_db = None
        if self.tool_sub is not None:
            self.tool_db = open_brain(self.cell, self.tool_sub, "status")
            self.dbs.append(self.tool_db)

    def close(self) -> None:
        self.tool_robot.close()
        self.hold.close()
        for db in self.dbs:
            db.close()

    def check_ready(self) -> None:
        for arm in (self.tool_robot, self.hold):
            rec = arm.read()
            arm.check_fresh(rec)
            if not int(rec["homed"]):
                raise RuntimeFailure(f"{arm.sub.name} is not homed: run 'droid-home {arm.sub.name}' first")
        if int(self.lead_db.read()["stale"]):
            raise RuntimeFailure(f"lead sensor {self.sensor_sub.name} is stale (no readings)")

    def go_to_start(self, position: str) -> None:
        T_tool, T_hold = self.layout.start_poses(position, self.args.wrist)
        resume = not self.args.no_resume
        self.resumes += move_to_start(self.hold, T_hold, f"holding pose of position ({position})",
                                      self.args.quiet, resume, self.cell)
        self.resumes += move_to_start(self.tool_robot, T_tool, f"start of position ({position})", self.args.quiet,
                                      resume, self.cell)

    # -- one tick: the station (droid.tasks.seam.station) between records and commands ----
    def arm_status(self, arm: BrainArm, rec) -> ArmStatus:
        """An arm's Brain Status record as the station reads it."""
        return ArmStatus(arm.sub.name, int(rec["tick"]), pose_of(rec), int(rec["fault"]), bool(int(rec["stale"])),
                         joints_deg=lambda: arm.joints_deg(rec))

    def read_lead(self) -> tuple[Reading, int]:
        """The lead sensor's newest reading and the tick of the Status it came in (read on a cycle)."""
        rec = self.lead_db.read()
        return reading_of(rec, self.cell.period_ns), int(rec["tick"])

    def on_tick(self, tick: int) -> str | None:
        """Read both arms' Status, run the station, write its commands; a stop's text or None."""
        rec, hold_rec = self.tool_robot.read(), self.hold.read()
        res = self.station.on_tick(tick, self.arm_status(self.tool_robot, rec), self.arm_status(self.hold, hold_rec),
                                   self.read_lead)
        if res.stop is not None:
            return str(res.stop)
        if res.tool_cmd is not None:
            self.tool_robot.command_cart(res.tool_cmd, self.station.cycle_ticks)
        if res.hold_cmd is not None:
            self.hold.command_cart(res.hold_cmd, self.station.cycle_ticks)
        self.log_due = res.log
        return None

    def log(self, t_s: float) -> None:
        """One 10 Hz row.  A tool-tip reading is placed at its capture instant (its stamp, else its
        Status tick minus the lag; TrackingCycle.place_tool): the row's travel is the tool's then."""
        tool = None
        out = self.station.out
        travel = out.travel_mm if out is not None else 0.0
        if self.tool_db is not None:
            rec = self.tool_db.read()
            tool = None if (int(rec["stale"]) or int(rec["homed"])) else reading_of(rec, self.cell.period_ns)
            if tool is not None:
                placed = self.cyc.place_tool(tool, int(rec["tick"]), self.wrist.T_wcp_tool)
                if placed is None:
                    tool = None  # its instant lies outside the pose history: dropped, counted
                elif math.isfinite(placed.travel_mm):
                    travel = placed.travel_mm
        self.rows.append(report.log_row(
            s_mm=travel, t_s=t_s, lead=self.station.lead,
            tool=None if tool is None else (tool.y_mm, tool.x_mm, tool.roll_rad),
            out=out, camera_to_tcp_mm=self.wrist.camera_to_tcp_mm))

    # -- the run -------------------------------------------------------------
    def run(self) -> tuple[int, str]:
        return run_on_ticks(self.cell, PROG, self._loop)  # the 30 Hz loop: below the remotes (50), SCHED_FIFO

    def _loop(self, ticks: TickSubscriber) -> tuple[int, str]:
        loop, last_progress = TickLoop(ticks), 0.0
        for t, now in loop:
            if self.t0 is None:
                self.t0 = t.t_ns
            if self.recorder is not None:
                self.recorder.on_tick(t.tick)
            # tick numbers follow time: a late wake-up (ticks drained at once) still steps once
            why = self.on_tick(t.tick)
            if why is not None:
                stop = self.core.stopped
                if stop is not None and stop.reason == STOP_END:
                    return EXIT_OK, why
                return EXIT_RUNTIME, why
            if self.log_due:
                self.log((t.t_ns - self.t0) / 1e9)
            o, lead = self.station.out, self.station.lead
            if not self.args.quiet and now - last_progress >= 1.0 and o is not None:
                last_progress = now
                print(f"{PROG}: {o.travel_mm:7.1f} mm  {o.phase:<9} lead y {lead.y_mm:+6.2f} "
                      f"x {lead.x_mm:+6.2f} mm{'' if lead.valid else ' (invalid)'}", file=sys.stderr)
        return loop.end


@run
def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    cell = open_cell(args)
    layout = layout_for_cell(cell, args.layout)
    tr = Tracker(args, cell, layout)
    check_output_dirs(args.log, args.figure, args.record)
    tr.connect()
    try:
        if args.record:
            from droid.observe.record import LiveRecorder

            tr.recorder = LiveRecorder(cell, args.record, layout_path=layout_path_for(cell, args.layout))
        code, why = ready_then_run(tr, args.start, "tracking", tr.run)
    finally:
        if tr.recorder is not None:
            tr.recorder.close()
        tr.close()
    stop = tr.core.stopped
    reason, detail = (stop.reason, stop.detail) if stop is not None else (why, "")
    last = tr.station.out
    s_end = stop.travel_mm if stop is not None else (last.travel_mm if last is not None else math.nan)
    summary = report.summarize(tr.rows, stop_reason=reason, stop_detail=detail, stop_s_mm=s_end,
                               camera_to_tcp_mm=tr.wrist.camera_to_tcp_mm, commanded_mm_s=args.speed)
    if args.log:
        report.write_csv(args.log, tr.rows)
    if args.figure:
        title = f"droid-seamtrack {args.speed:g} mm/s" + (f", position ({args.start})" if args.start else "")
        report.figure(args.figure, tr.rows, title, panels="errors")
    say_outcome(PROG, why, report.summary_line(summary) + summary_note(tr.resumes), args.log, args.figure)
    return code


if __name__ == "__main__":
    sys.exit(main())
