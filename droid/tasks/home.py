"""droid-home ROBOT: home an arm (thesis §3.4 "The Home program", §4.1.5.3).

"The Home program is a generic robot program which initiates the homing
routine by changing the Command Mode to the HOME value.  Once the home signal
has been sent to the robot, the robot takes care of the homing itself with no
further control from the Home program."  This program then waits until the
Status record says HOMED and sets the command mode to NORMAL (§3.3: "the
robot's command mode is placed in HOME mode until it has completed its homing
procedure at which point its command mode becomes NORMAL").

What homing means is the robot's business: the Reis servo searches each
joint's limit switch; the Fanuc bridge sends its controller home and zeroes
the encoder cards (docs/gmf1.md).

Exit 0 when homed; 1 on failure (stale, fault, timeout) with the reason.
"""
from __future__ import annotations

import sys

from droid.brain.runtime.program import open_cell, parser
from droid.brain.db.layouts import CMD_OK
from droid.cli import run, timeout_s
from droid.tasks.arm import BrainArm, Interrupted

PROG = "droid-home"
DEFAULT_TIMEOUT_S = 180.0


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Home an arm and wait until it reports HOMED.")
    ap.add_argument("robot", help="arm subunit, e.g. arm1")
    ap.add_argument("--timeout", type=timeout_s, default=DEFAULT_TIMEOUT_S, metavar="S",
                    help=f"give up after S seconds (default {DEFAULT_TIMEOUT_S:g})")
    args = ap.parse_args(argv)
    cell = open_cell(args)
    with BrainArm(cell, args.robot) as arm:
        arm.connect()
        home(arm, args.timeout)
    return 0


def home(arm: BrainArm, timeout: float = DEFAULT_TIMEOUT_S, interrupted=None):
    """Home the connected ``arm``: wait until idle, command HOME, wait until it reports HOMED, set
    the command mode NORMAL; its last Status record.  RuntimeFailure (stale, fault, timeout) or
    BadInput (refused) with the reason; ``interrupted()`` true while waiting: the homing is stopped
    (:meth:`BrainArm.give_up`) and Interrupted raised.  droid-home's body; droid-ros2's /<arm>/home."""
    stop = interrupted or (lambda: False)
    arm.check_fresh()
    arm.wait_idle(timeout)
    cmd_id = arm.command_home()
    arm.wait_delivered(cmd_id, timeout)
    rec = arm.wait(lambda r: stop() or (int(r["cmd_id"]) == cmd_id and int(r["busy"]) == 0
                                        and (int(r["homed"]) or int(r["cmd_result"]) != CMD_OK)),
                   timeout, f"{arm.sub.name} to report HOMED")
    if stop():
        arm.give_up()
        raise Interrupted(f"interrupted while {arm.sub.name} homed: stopped where it stood")
    arm.check_result(rec, cmd_id)
    arm.set_normal()
    return rec


if __name__ == "__main__":
    sys.exit(main())
