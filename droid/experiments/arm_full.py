"""The ``full`` arm model for the trial harness: every core of the real-time arm subunit.

:class:`droid.sim.reis.cell.LockstepArm` runs the plant (2 kHz joint
dynamics behind the VME register map), the 500 Hz servo core (PID, queue,
braking), the watchdog, the servo agent, the planner and the remote's FK on
the trial's scheduler.  A trial first homes the arm (the servo's homing from
a random power-up pose, §4.1.5.3) and moves it to the start pose with a joint
command, then the seam-tracking core drives it with cartesian commands
through the Brain Command record, exactly as droid-seamtrack does.

The arm is the trial cell's welder (droid.experiments.trial_cell; without a cell file the
built-in cell's Reis), built by its package's lockstep builder: the Reis as above, or the ABB on
EGM (droid.sim.abb.lockstep.LockstepAbbArm: droid-egm and the controller twin; it homes at once).

The experiments' default arm model (issue 13 item 5): every repetition homes from its own
seeded power-up pose, so experiment 4 measures repeatability.  ~5-10x slower than the
``fast`` model (droid.sim.reis.fast_arm; docs/benchmarks.md).
"""
from __future__ import annotations

import numpy as np

from droid.cli import RuntimeFailure
from droid.experiments import phases
from droid.kinematics.transforms import record_pose
from droid.sim.lockstep import Scheduler

HOME_TIMEOUT_S = 60.0
MOVE_S = 4.0  # the move from home to the start pose
SETTLE_S = 1.0


class FullArm:
    """An arm subunit's cores on a scheduler, with the harness's arm interface.

    ``arm``: the lockstep arm its package's builder built on ``sched`` -- a droid.arm.protocol.Arm that
    also shows the world's ``wcp_global`` (a builder declared with ``truth``: the Reis's
    :class:`~droid.sim.reis.cell.LockstepArm`, droid.sim.abb.lockstep.LockstepAbbArm, a lab's own; the
    trial cell's welder, built by droid.experiments.trial_cell.TrialCell.build_arms) whose robot model
    is ``model``."""

    def __init__(self, sched: Scheduler, model, q_start_deg, arm) -> None:
        self.sched = sched
        self.model = model
        self.arm = arm
        self.q_start = np.asarray(q_start_deg, float)

    def prepare(self) -> None:
        """Home (the Reis searches its switches; the ABB measures absolutely and homes at once),
        then move to the start pose; raises RuntimeFailure if either does not finish."""
        if not self.arm.home(HOME_TIMEOUT_S):
            raise RuntimeFailure(f"full arm model {self.name}: homing did not finish")
        phases.mark("homed", self.sched)
        counts = np.rint(self.model.gearing.joints_to_counts(self.q_start)).astype(np.int32)
        cmd = self.arm.command_joint(counts, self.arm.ticks_for(MOVE_S))
        if not self.arm.move_done(cmd, MOVE_S + 5.0):
            raise RuntimeFailure(f"full arm model {self.name}: the move to the start pose did not finish")
        self.sched.run_for(SETTLE_S)
        phases.mark("approached", self.sched)

    def command_cart(self, T_global_wcp, ticks: int) -> None:
        self.arm.command_cart(T_global_wcp, ticks)

    def status_pose(self) -> np.ndarray:
        return record_pose(self.arm.read())

    def status_joints(self) -> np.ndarray:
        return self.model.gearing.counts_to_joints(np.asarray(self.arm.read()["encoder_pos"], float))

    @property
    def name(self) -> str:
        """The arm's subunit name (arm1; the layout's tool_robot on a cell)."""
        return self.arm.name

    def status_fault(self) -> int:
        """The Brain Status ``fault`` bits (FAULT_*), as droid-seamtrack reads them."""
        return int(self.arm.read()["fault"])

    def true_wcp(self) -> np.ndarray:
        return self.arm.wcp_global()

    def tick(self) -> None:  # the cores run on the scheduler by themselves
        pass
