"""What a task drives of one arm: :class:`Arm` (thesis §3.4; docs/design.md §12 "One arm, many families").

"A Task program ... reads these databases and ... modifies the command databases of the subunit
to be commanded": whatever family the arm is (the Reis, the GMF1, the ABB, a lab's own) and
whichever runner carries it, a task sees the arm's Brain Status and Command records through the
same few calls.  Two runners satisfy it:

* real time: :class:`droid.tasks.arm.BrainArm` (the records in shared memory; waits on the wall
  clock);
* lockstep: the ``arm`` of every lockstep builder's :class:`~droid.sim.lockstep_build.LockstepSubunit`
  (:class:`droid.sim.arm_chain.ArmTasks` and its subclasses: the Reis's ``LockstepArm``, the ABB's
  ``LockstepAbbArm``, the GMF1's ``ArmTasks`` over its records; waits advance virtual time).

Commands are counted in heartbeat ticks (:mod:`droid.brain.db.arm_command`); every ``command_*`` returns
the ``cmd_id`` it wrote.  ``home`` and ``move_done`` wait at most ``timeout_s`` seconds and say whether
the arm got there (True) or not (False): neither raises for an arm that did not finish in time.

This module imports nothing of droid, so a task may type against it (docs/design.md §7).
"""
from __future__ import annotations

from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class Arm(Protocol):
    """One arm as a task drives it (see the module docstring)."""

    @property
    def name(self) -> str:
        """The arm's subunit name (``arm1``; the layout's ``tool_robot`` or ``holder_robot``)."""
        ...

    def read(self) -> Any:
        """The arm's newest Brain Status record (thesis Table 3.1: pose, ``encoder_pos``, ``busy``,
        ``homed``, ``cmd_id``, ``cmd_result``, ``fault``, ``stale``, ...)."""
        ...

    def command_home(self) -> int:
        """Write HOME (thesis §3.4 "The Home program"); the command's ``cmd_id``."""
        ...

    def command_joint(self, counts, ticks: int) -> int:
        """A joint move to ``counts`` [encoder counts wrt home] in ``ticks`` heartbeat ticks."""
        ...

    def command_cart(self, T, ticks: int) -> int:
        """A cartesian move of the wrist centre to ``T`` (4x4, global frame, mm) in ``ticks`` ticks."""
        ...

    def ticks_for(self, seconds: float) -> int:
        """``seconds`` [s] as heartbeat ticks of the arm's cell."""
        ...

    def set_normal(self) -> None:
        """Command mode NORMAL (after homing, thesis §3.3); no new command."""
        ...

    def home(self, timeout_s: float = 60.0) -> bool:
        """droid-home: HOME, wait until homed and idle (at most ``timeout_s`` [s]), then NORMAL;
        whether it homed."""
        ...

    def move_done(self, cmd_id: int, timeout_s: float) -> bool:
        """Wait until the Status acknowledges ``cmd_id`` and is idle (at most ``timeout_s`` [s]);
        whether it did."""
        ...
