"""A task's hold on a force/torque subunit's Brain Command (class ``ft6``; thesis §7.3).

The Brain's Command record of an ``ft6`` subunit (``ft6_command``) carries two requests to
droid-ft on the sensor's host, copied there by droid-agent like an arm's (Table 3.2's ``sent``
and ``cmd_id`` included): a new ``bias_id`` biases the sensor once (the device subtracts its
present reading from every later one), and ``guard_force_n`` arms the over-force guard on the
arm the sensor sits on (``[subunits.X] guard_arm``: droid-ft sets FAULT_FORCE in that arm's own
Status while |F| is above it, and the arm's planner cancels its move; 0 disarms it).
"""
from __future__ import annotations

from droid.brain.db.databases import open_brain, write_command
from droid.cli import BadInput
from droid.numbers import Range

U32 = 0xFFFFFFFF
#: The guard limits a task may arm [N] (0 disarms).
GUARD_FORCE_N = Range(0.0, 10000.0, "N")


class BrainFt:
    """``write(bias=..., guard_force_n=...)`` one Command; ``delivered(cmd_id)`` once the agent
    took it (``sent`` cleared by droid-remote on the agent's acknowledgement)."""

    def __init__(self, cell, name: str) -> None:
        self.sub = cell.subunit(name)
        self.sub.check_class("ft6", "an ft6 force/torque sensor")
        self.cell = cell
        self.command = None

    def connect(self) -> "BrainFt":
        """Attach to the Brain's Command record (RuntimeFailure if the cell is not up)."""
        self.command = open_brain(self.cell, self.sub, "command")
        return self

    def close(self) -> None:
        if self.command is not None:
            self.command.close()
            self.command = None

    def write(self, *, bias: bool = False, guard_force_n: float | None = None) -> int:
        """One Command: a bias if ``bias``, the guard set to ``guard_force_n`` [N] if given (else
        kept); returns its ``cmd_id``.  A limit outside GUARD_FORCE_N raises BadInput."""
        if guard_force_n is not None:
            try:
                guard_force_n = GUARD_FORCE_N.check(guard_force_n, "guard_force_n")
            except ValueError as exc:  # NumberError
                raise BadInput(str(exc)) from None
        fields = {}
        if bias:  # the next bias_id (a task is the Command's one writer, as for an arm's)
            fields["bias_id"] = (int(self.command.read()["bias_id"]) + 1) & U32
        if guard_force_n is not None:
            fields["guard_force_n"] = guard_force_n
        return write_command(self.command, **fields)

    def delivered(self, cmd_id: int) -> bool:
        """The agent acknowledged command ``cmd_id`` (or a later one replaced it)."""
        rec = self.command.read()
        return int(rec["cmd_id"]) != cmd_id or not int(rec["sent"])
