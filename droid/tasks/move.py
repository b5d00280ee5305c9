"""droid-move ROBOT joint E1..E6 SECONDS | ROBOT cart X Y Z A B C SECONDS (thesis §3.4).

"The Move program is a generic robot program which commands movement to the
robot in a specified time. ... it checks to see whether the robot is available
for a move command via the Busy field in the status memory database. It then
waits until the previous move is completed before writing to the command
memory area.  Joint mode commands require six encoder count values relative to
the zero or home position, while cartesian mode commands require an x, y, and z
position as well as the ... angles of the final 3 joints (in degrees)."

* ``joint E1..E6``: encoder counts relative to home;
* ``cart X Y Z A B C``: wrist-centre position [mm] and ZYZ Euler angles [deg]
  in the global frame (eq. 4.2);
* ``SECONDS``: the time to complete the move (``× heartbeat rate`` ticks).

The target is checked against the robot model first — joint and encoder
limits, reachability, joint speed limits — and a bad target exits 2 with the
reason before anything is written: the robot does not move.  Then the program
waits for ``busy == 0``, writes the command, and waits until the robot reports
it finished and is within 0.05 joint degrees of the target (``--no-wait``: until
the agent has it).  Exit 1 if the arm is not homed, stale, does not finish in
time, or halted short of its target; a move given up on (timeout, stale,
Ctrl-C, SIGTERM: exit 130) is stopped (a stop command is written over it) so it
is never carried out later.  SECONDS is at most 3600 (one hour).

Where the cell declares a collision guard (``[guard]``, docs/guard.md), the move's joint path
is sampled against the other arms (where they stand, or along their joint moves) before it is
written; one that would come closer than the guard's clearance is refused, exit 2, with one
line such as ``would collide: arm1 link 4 with gmf1 link 3 at 42 % of the move (clearance 12 mm
< 25 mm)``: the arm never moves.  ``--wait-clear S`` coordinates instead: a move that would
collide only with another arm's running move holds until that move has cleared the region (at
most S seconds; ``arm1: holding until gmf1's move clears the region (...)`` on stderr), then goes.

A move a protective stop cancelled -- the servo ran out of commands and braked
(FAULT_BRAKING, e.g. after a host stall) and nothing else faulted -- is re-issued
toward the same target from where the arm came to rest, at most 3 times
(droid.tasks.resume, BrainArm.move), each with a line on stderr such as
``arm1: protective stop at 41 % of the move (braking); resuming from the arm's
position (1 of 3)`` (the share of the move's joint-space distance covered), and
``arm1: arrived after 1 resume`` at the end; ``--no-resume`` fails it instead
(exit 1, as any failed move).  ``--timeout`` bounds each wait of each move.
"""
from __future__ import annotations

import signal
import sys

import numpy as np

from droid.brain.runtime.program import open_cell, parser
from droid.cli import MAX_MOVE_S, RuntimeFailure, finite_float, run, timeout_s
from droid.tasks.arm import MAX_CART_ANGLE_DEG, BrainArm
from droid.tasks.guarded import refuse_colliding_move
from droid.tasks.resume import MAX_RESUMES, arrived_line

PROG = "droid-move"


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Move an arm to a joint (encoder counts) or cartesian (mm, ZYZ deg) target "
                      "in SECONDS.")
    ap.add_argument("robot", help="arm subunit, e.g. arm1")
    ap.add_argument("mode", choices=("joint", "cart"), help="joint: E1..E6 [counts]; cart: X Y Z [mm] A B C [deg]")
    ap.add_argument("values", nargs="+", type=finite_float, metavar="V",
                    help=f"6 target values (joint: E1..E6 [counts]; cart: X Y Z [mm] A B C [deg], |A|,|B|,|C| <= "
                         f"{MAX_CART_ANGLE_DEG:g}), then SECONDS, the move time; range (0, {MAX_MOVE_S:g}] s")
    ap.add_argument("--no-wait", action="store_true", help="return once the command is delivered")
    ap.add_argument("--timeout", type=timeout_s, default=None, metavar="S",
                    help="give up waiting after S seconds (default: 2 x move time + 10 s; each resumed move "
                         "its own)")
    ap.add_argument("--no-resume", action="store_true",
                    help=f"fail a move a protective stop (braking) cancelled instead of resuming it from "
                         f"where the arm stopped (at most {MAX_RESUMES} times)")
    ap.add_argument("--wait-clear", type=timeout_s, default=0.0, metavar="S",
                    help="where the cell has a collision guard: a move that would collide with another arm's "
                         "running move holds until that move clears the region, for at most S seconds, "
                         "instead of being refused at once")
    args = ap.parse_args(argv)
    if len(args.values) != 7:
        ap.error(f"{args.mode} needs 6 target values and SECONDS, got {len(args.values)} numbers")
    *target, seconds = args.values
    if not 0 < seconds <= MAX_MOVE_S:
        ap.error(f"SECONDS must be > 0 and <= {MAX_MOVE_S:g} s (one hour), got {seconds:g}")
    cell = open_cell(args)
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # as Ctrl-C: the move is stopped (exit 130)
    with BrainArm(cell, args.robot) as arm:
        ticks = arm.ticks_for(seconds)  # refused before the cell is touched
        check = arm.check_joint_target if args.mode == "joint" else arm.check_cart_target
        check(target, seconds, None)  # limits and reachability: needs no cell
        arm.connect()
        rec = check_ready(arm)
        checked = check(target, seconds, arm.joints_deg(rec))  # speed from here, before waiting
        # the collision guard's bodies (a cell with a [guard] table): a move that would collide is
        # refused here, exit 2, before anything is written (docs/guard.md)
        q_goal = (arm.model.gearing.counts_to_joints(np.asarray(checked, float)) if args.mode == "joint"
                  else checked[1])
        held = refuse_colliding_move(cell, args.robot, arm.joints_deg(rec), q_goal, seconds, args.wait_clear)
        if held:
            print(f"{args.robot}: the region cleared after {held:.1f} s; moving", file=sys.stderr)
        if args.no_wait:
            timeout = args.timeout or 2 * seconds + 10.0
            q_now = arm.joints_deg(arm.wait_idle(timeout))
            cmd_id, _, _ = arm.write_move(args.mode, target, seconds, ticks, q_now)
            arm.wait_delivered(cmd_id, timeout)
            return 0
        resumes = arm.move(args.mode, target, seconds, resume=not args.no_resume,
                           timeout=lambda s: args.timeout or 2 * s + 10.0)
        if resumes:  # "done" short of the target is a failure (exit 1): move() checks arrival
            print(arrived_line(args.robot, resumes), file=sys.stderr)
    return 0


def check_ready(arm: BrainArm):
    """The connected ``arm``'s Status record if it may take a move: fresh, able to move and homed;
    else RuntimeFailure with the reason (droid-move's rule, and droid-ros2's for a trajectory)."""
    rec = arm.read()
    arm.check_fresh(rec)
    if not int(rec["homed"]):
        raise RuntimeFailure(f"{arm.sub.name} is not homed: run 'droid-home {arm.sub.name}' first "
                             f"(droid-jog moves it before homing)")
    return rec


if __name__ == "__main__":
    sys.exit(main())
