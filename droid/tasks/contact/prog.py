"""droid-contact ARM: press the tool on a surface and slide along it holding a normal force
(issue 27 item 5; thesis §7.3, "force/torque control" on the standard interface).

The real-time shell of the force task.  The core is
:class:`droid.tasks.contact.core.ContactStation` -- the same station the lockstep trial
runs (droid.experiments.contact_trial) -- and this program does, on the Brain's databases
only (a task never touches a device, §3.4), what droid-seamtrack does around its station:

1. attach to the Status/Command records of ARM (the tool robot), the Status of the wrist
   F/T sensor (``--ft``, class ft6) and, with ``--start``, the holder's records;
2. with ``--start POSITION``: move the holder to its holding pose of that layout position
   (droid/cells/seamtrack_layout.toml, as droid-seamtrack) and then ARM so that its
   touching point stands ``--clearance`` mm above the step workpiece's lower plate,
   ``--lateral`` mm beside the seam, the tool axis along the surface normal; a start
   move a protective stop cancelled (braking alone) is resumed from where the arm
   stopped, at most 3 times (as droid-seamtrack's: BrainArm.move; ``--no-resume``: exit 1
   instead), and the summary line ends with ``; start moves: N resume(s) after a
   protective stop`` when there was any;
3. tare: bias the sensor through its Brain Command (the device subtracts its present
   reading -- the tool's weight in this orientation, its offset -- from what follows), then
   average the F/T Status's ``force_tool_N`` over ``TARE_S`` at rest, off the surface, and
   subtract that residue too -- the orientation does not change during the task -- and arm
   the sensor's over-force guard at the gains' ``force_max_n``: droid-ft, on the arm's host,
   sets FAULT_FORCE in the arm's own Status past it and the arm's planner cancels the move
   within its next tick, without the two Brain exchanges the task's own check goes through
   (the cell's ``[subunits.FT] guard_arm``; without it only the task's check stops).  The
   guard is disarmed when the program ends, whatever the stop;
4. every heartbeat tick hand the arm's Status pose and the tared force to the station;
   every ``cycle_ticks`` ticks (the gains file: 30 Hz at 60 Hz) it approaches along the
   tool axis until touch, settles, then slides ``--length`` mm at ``--speed`` holding
   ``--force`` by admittance; its cartesian command is written for one cycle of ticks;
5. stop -- at the path's end no new command is written, so the arm finishes its last
   one-cycle step and stands; at any other stop a stop command (STOP_TICKS) is written over
   the step in progress, so the arm stands where it is -- on over-force (checked every tick), contact loss, no contact within the
   approach, a stale or invalid F/T Status, an arm fault it cannot move with or a protective
   stop (braking, collision: ``FAULTS_STOP_RUN``, a press that stopped is a defect), a stale arm
   Status, a lost heartbeat, or SIGINT/SIGTERM -- the approach and the pressing are never
   resumed; an arm fault names its bits (``arm fault (fault bits 0x4: servo)``).  Then print which, and the summary line
   ``normal force RMS error X N, max Y N ...`` (droid.tasks.contact.report); the ``--log``
   CSV and ``--figure`` PNG are written whatever the stop.

The touching point is the torch's gas nozzle, ``--touch-offset`` mm back from the layout
wrist's tool point along the tool axis (default 15 mm, the simulated cell's contact device:
cells/sim.toml ``[world.devices.touch]``; docs/contact.md).

Exit codes: 0 the path's end; 130 interrupted; 1 any other stop, an arm not homed or
faulted before anything moves, the cell not up; 2 bad arguments, gains or layout (nothing
moves).
"""
from __future__ import annotations

import sys
import time

import numpy as np

from droid.brain.db.databases import open_brain
from droid.brain.runtime.heartbeat import TickSubscriber
from droid.brain.runtime.program import open_cell, parser
from droid.cli import EXIT_OK, EXIT_RUNTIME, BadInput, RuntimeFailure, bounded_float, run
from droid.kinematics.transforms import inv_homo, trans
from droid.tasks.arm import BrainArm
from droid.tasks.ft_sensor import BrainFt
from droid.tasks.resume import MAX_RESUMES, summary_note
from droid.tasks.contact import report
from droid.tasks.contact.core import STOP_END, ArmStatus, ContactStation, FtStatus, load_gains
from droid.brain.cell.cell_layout import POSITION_IDS, T_W_SEAM, layout_for_cell
from droid.tasks.shell import TickLoop, check_output_dirs, ready_then_run, run_on_ticks, say_outcome
from droid.tasks.seamtrack import move_to_start

PROG = "droid-contact"
TARE_S = 0.5  # the F/T average taken at rest before the approach [s]
DELIVERY_S = 2.0  # the longest wait for the sensor's agent to take its bias command [s]
BIAS_SETTLE_S = 0.1  # then droid-ft (100 Hz) sends the bias and the device applies it [s]
MAX_SPEED_MM_S = 100.0
MAX_LENGTH_MM = 2000.0
DEFAULT_TOUCH_OFFSET_MM = 15.0

speed_mm_s = bounded_float(0.0, MAX_SPEED_MM_S, "mm/s", lo_open=True)
length_mm = bounded_float(0.0, MAX_LENGTH_MM, "mm", lo_open=True)
force_n = bounded_float(0.0, 10000.0, "N", lo_open=True)  # and below the gains' force_max_n (checked after)
offset_mm = bounded_float(-500.0, 500.0, "mm")
clearance_mm = bounded_float(0.0, 100.0, "mm", lo_open=True)


def build_parser():
    ap = parser(PROG, "Touch the surface under ARM's tool and slide along it holding a normal force "
                      "(admittance on the cartesian commands; docs/contact.md).")
    ap.add_argument("arm", metavar="ARM", help="the arm carrying the F/T sensor and the tool (e.g. arm1)")
    ap.add_argument("--force", type=force_n, default=20.0, metavar="N",
                    help="normal force to hold [N], in (0, the gains' force_max_n) (default 20)")
    ap.add_argument("--speed", type=speed_mm_s, default=10.0, metavar="MM_S",
                    help=f"speed along the path [mm/s], in (0, {MAX_SPEED_MM_S:g}] (default 10)")
    ap.add_argument("--length", type=length_mm, default=200.0, metavar="MM",
                    help=f"path length [mm], in (0, {MAX_LENGTH_MM:g}] (default 200)")
    ap.add_argument("--start", choices=POSITION_IDS, default=None, metavar="POSITION",
                    help="first move the holder and ARM over the workpiece's lower plate at this layout "
                         "position (i..vii; as droid-seamtrack --start)")
    ap.add_argument("--ft", default="ft", metavar="SUBUNIT", help="the wrist F/T sensor (class ft6; default ft)")
    ap.add_argument("--gains", metavar="FILE", default=None,
                    help="the controller's gains (default: the bundled droid/tasks/contact/gains.toml)")
    ap.add_argument("--layout", metavar="FILE", default=None,
                    help="seam-tracking layout for --start (default: the bundled one)")
    ap.add_argument("--wrist", default="standard", metavar="NAME", help="wrist set-up of the layout")
    ap.add_argument("--touch-offset", type=offset_mm, default=DEFAULT_TOUCH_OFFSET_MM, metavar="MM",
                    help="the touching point, this far back from the wrist's tool point along the tool axis "
                         f"[mm] (default {DEFAULT_TOUCH_OFFSET_MM:g}: the gas nozzle)")
    ap.add_argument("--lateral", type=offset_mm, default=-25.0, metavar="MM",
                    help="with --start: the path's distance beside the seam, + = the upper plate's side "
                         "[mm] (default -25: the lower plate)")
    ap.add_argument("--clearance", type=clearance_mm, default=5.0, metavar="MM",
                    help="with --start: the touching point's height above the plate [mm] (default 5)")
    ap.add_argument("--log", metavar="FILE", default=None, help="write the per-cycle CSV log here")
    ap.add_argument("--figure", metavar="FILE", default=None, help="draw the run's figure (PNG) here")
    ap.add_argument("--no-resume", action="store_true",
                    help="with --start: fail a start move a protective stop (braking) cancelled instead of "
                         f"resuming it from where the arm stopped (at most {MAX_RESUMES} times)")
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return ap


class ContactRun:
    """The loop around the station (the module docstring)."""

    def __init__(self, args, cell) -> None:
        self.args = args
        self.cell = cell
        self.gains = load_gains(args.gains, cell.heartbeat_hz)
        if not args.force < self.gains.force_max_n:
            raise BadInput(f"--force {args.force:g} N: must be < force_max_n {self.gains.force_max_n:g} N "
                           f"(the gains' over-force stop)")
        self.arm = BrainArm(cell, args.arm)
        self.ft_sub = cell.subunit(args.ft)
        if self.ft_sub.cls != "ft6":
            raise BadInput(f"--ft {args.ft}: is a {self.ft_sub.cls} subunit, not a force/torque sensor (ft6)")
        self.layout = layout_for_cell(cell, args.layout)
        self.wrist = self.layout.wrist(args.wrist)
        self.T_wcp_touch = self.wrist.T_wcp_tool @ trans(-args.touch_offset, 0.0, 0.0)
        self.holder = None
        if args.start is not None:
            if args.arm != self.layout.tool_robot:
                raise BadInput(f"--start: the layout {self.layout.source} puts the tool on "
                               f"{self.layout.tool_robot}, not {args.arm}")
            self.layout.position(args.start)
            self.holder = BrainArm(cell, self.layout.holder_robot)
        self.station = ContactStation(self.gains, cell.heartbeat_hz, self.T_wcp_touch, args.force, args.speed,
                                      args.length)
        self.period_s = 1.0 / cell.heartbeat_hz
        self.tare = np.zeros(3)
        self.rows: list[tuple] = []
        self.t0_tick: int | None = None
        self.prev: tuple[int, float] | None = None  # (tick, along_mm) of the last logged cycle
        self.ft_db = None
        self.ft_cmd = BrainFt(cell, args.ft)
        self.guarded = self.ft_sub.options.get("guard_arm") == args.arm
        self.resumes = 0  # the start moves' resumes after a protective stop (BrainArm.move)

    # -- set-up ----------------------------------------------------------------------------
    def connect(self) -> None:
        self.arm.connect()
        if self.holder is not None:
            self.holder.connect()
        self.ft_db = open_brain(self.cell, self.ft_sub, "status")
        self.ft_cmd.connect()

    def close(self) -> None:
        if self.ft_cmd.command is not None:
            try:  # disarm the guard this run armed (a stop leaves the arm standing: no motion)
                self.ft_cmd.write(guard_force_n=0.0)
            finally:
                self.ft_cmd.close()
        self.arm.close()
        if self.holder is not None:
            self.holder.close()
        if self.ft_db is not None:
            self.ft_db.close()

    def check_ready(self) -> None:
        for arm in (self.arm, self.holder):
            if arm is None:
                continue
            rec = arm.read()
            arm.check_fresh(rec)
            if not int(rec["homed"]):
                raise RuntimeFailure(f"{arm.sub.name} is not homed: run 'droid-home {arm.sub.name}' first")
        rec = self.ft_db.read()
        if int(rec["stale"]) or not int(rec["valid"]):
            raise RuntimeFailure(f"{self.ft_sub.name} is {'stale' if int(rec['stale']) else 'not valid'} "
                                 f"(no F/T readings)")

    def start_pose(self, position: str) -> tuple[np.ndarray, np.ndarray]:
        """(ARM's WCP, the holder's WCP) at ``position`` (4x4, mm, global): the touching point
        ``--clearance`` above the plate, ``--lateral`` beside the seam, at the seam's start."""
        _, T_hold = self.layout.start_poses(position, self.args.wrist)
        pos = self.layout.position(position)
        T_gW = pos.T_global_W(self.wrist.camera_to_tcp_mm)
        T_touch = T_gW @ trans(0.0, self.args.lateral, self.args.clearance) @ T_W_SEAM
        return T_touch @ inv_homo(self.T_wcp_touch), T_hold

    def go_to_start(self, position: str) -> None:
        T_arm, T_hold = self.start_pose(position)
        resume = not self.args.no_resume
        self.resumes += move_to_start(self.holder, T_hold, f"holding pose of position ({position})",
                                      self.args.quiet, resume, self.cell)
        self.resumes += move_to_start(self.arm, T_arm, f"start over position ({position})", self.args.quiet, resume,
                                      self.cell)

    def bias_sensor(self) -> None:
        """Bias the sensor through its Command, and wait until its agent took it (the module
        docstring, step 3); RuntimeFailure if it is not delivered within DELIVERY_S."""
        cmd_id = self.ft_cmd.write(bias=True, guard_force_n=0.0)
        deadline = time.monotonic() + DELIVERY_S
        while not self.ft_cmd.delivered(cmd_id):
            if time.monotonic() > deadline:
                raise RuntimeFailure(f"{self.ft_sub.name}: its bias command was not delivered within "
                                     f"{DELIVERY_S:g} s")
            time.sleep(0.01)
        time.sleep(BIAS_SETTLE_S)  # droid-ft reads the command and the device biases the next records

    def arm_guard(self) -> None:
        """The sensor's over-force guard at the gains' force_max_n [N] (step 3)."""
        self.ft_cmd.write(guard_force_n=self.gains.force_max_n)
        if not self.args.quiet:
            where = (f"droid-ft sets FAULT_FORCE on {self.args.arm}" if self.guarded else
                     f"{self.ft_sub.name} has no guard_arm = \"{self.args.arm}\": only this task's check stops")
            print(f"{PROG}: over-force guard at {self.gains.force_max_n:g} N ({where})", file=sys.stderr)

    def take_tare(self) -> None:
        """The mean F/T force over TARE_S at rest (the module docstring, step 3)."""
        deadline = time.monotonic() + TARE_S
        seen: dict[int, np.ndarray] = {}
        while time.monotonic() < deadline or not seen:
            rec = self.ft_db.read()
            if int(rec["stale"]) or not int(rec["valid"]):
                raise RuntimeFailure(f"{self.ft_sub.name} went stale or invalid before the approach")
            seen[int(rec["rdt_seq"])] = np.asarray(rec["force_tool_N"], float).copy()
            if time.monotonic() > deadline + 2.0:
                break
            time.sleep(0.01)
        self.tare = np.mean(list(seen.values()), axis=0)
        if not self.args.quiet:
            print(f"{PROG}: tare {np.round(self.tare, 2).tolist()} N (tool frame, {len(seen)} records)",
                  file=sys.stderr)

    # -- one tick ------------------------------------------------------------------------------
    def on_tick(self, tick: int) -> str | None:
        rec = self.arm.read()
        f = self.ft_db.read()
        arm = ArmStatus.of_record(rec)
        ft = FtStatus(np.asarray(f["force_tool_N"], float) - self.tare, bool(int(f["valid"])), bool(int(f["stale"])))
        out = self.station.on_tick(tick, arm, ft)
        if out.cmd is not None:
            self.arm.command_cart(out.cmd, out.ticks)
        if out.cycle and self.station.T0 is not None:
            self.log(tick, arm.pose, ft.normal_n)
        return out.stop

    def log(self, tick: int, pose: np.ndarray, normal_n: float) -> None:
        st = self.station
        if self.t0_tick is None:
            self.t0_tick = tick
        d = (pose @ self.T_wcp_touch)[:3, 3] - st.T0[:3, 3]
        normal_mm, along_mm = float(d @ st.T0[:3, 0]), float(d @ st.T0[:3, 2])
        speed = 0.0
        if self.prev is not None and tick > self.prev[0]:
            speed = (along_mm - self.prev[1]) / ((tick - self.prev[0]) * self.period_s)
        self.prev = (tick, along_mm)
        phase = st.phase if st.phase != "done" else (self.rows[-1][1] if self.rows else "approach")
        self.rows.append(((tick - self.t0_tick) * self.period_s, phase, normal_n, self.args.force - normal_n,
                          st.depth_mm, normal_mm, along_mm, speed))

    # -- the run ---------------------------------------------------------------------------------
    def tare_and_run(self) -> tuple[int, str]:
        """The sensor biased and tared at rest, the guard armed, then :meth:`run`."""
        self.bias_sensor()
        self.take_tare()
        self.arm_guard()
        return self.run()

    def run(self) -> tuple[int, str]:
        return run_on_ticks(self.cell, PROG, self._loop)

    def _loop(self, ticks: TickSubscriber) -> tuple[int, str]:
        loop, last_progress = TickLoop(ticks), 0.0
        for t, now in loop:
            stop = self.on_tick(t.tick)
            if stop is not None:
                if stop != STOP_END:
                    self.arm.give_up()  # a stop over the step in progress: the arm stands where it is
                detail = self.station.detail
                return (EXIT_OK if stop == STOP_END else EXIT_RUNTIME), stop + (f" ({detail})" if detail else "")
            if not self.args.quiet and now - last_progress >= 1.0 and self.rows:
                last_progress = now
                r = self.rows[-1]
                print(f"{PROG}: {r[1]:<8} force {r[2]:6.2f} N  along {r[6]:7.1f} mm", file=sys.stderr)
        self.arm.give_up()  # interrupted, or the heartbeat lost
        return loop.end


@run
def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    check_output_dirs(args.log, args.figure)
    cell = open_cell(args)
    job = ContactRun(args, cell)
    job.connect()
    try:
        code, why = ready_then_run(job, args.start, "the approach", job.tare_and_run)
    finally:
        job.close()
    st = job.station
    s = report.summary(job.rows)
    if args.log:
        report.write_csv(args.log, job.rows)
    if args.figure:
        report.figure(args.figure, job.rows, f"{PROG} {args.arm}: {args.force:g} N at {args.speed:g} mm/s"
                      + (f", position ({args.start})" if args.start else ""), args.force)
    say_outcome(PROG, why, s.line(args.force, args.speed, args.length, st.done or why.split(" (")[0], st.detail)
                + summary_note(job.resumes), args.log, args.figure)
    return code


if __name__ == "__main__":
    sys.exit(main())
