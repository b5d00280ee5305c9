"""One cycle of each GMF1 program around its core: read -> core.step -> write (ros2_control style).

Shared by the real-time shells (droid-gmf1-serial, droid-gmf1-encoder) and the
lockstep runner, so both modes run exactly the same code between the records,
the port or the cards, and the cores.  The records may be shared-memory
:class:`~droid.brain.db.shmdb.Database` objects or lockstep
:class:`~droid.brain.db.shmdb.MemoryDatabase` objects.

Both programs write the controller's Status record (Table 4.2); each owns its
fields:

* serial: busy, cmd_id, cmd_result, cmd_mode, coord, encoder_cmd, and homed := 0
  when it sends HOME;
* encoder: encoder_pos, x, y, z, R, updated_ns, and homed := 1 after zeroing.

FAULT_DEVICE is shared: each program asserts it every cycle while its fault
lasts and clears it only when its own fault ends, so one program's recovery
hides the other's fault for at most one cycle of the other.
"""
from __future__ import annotations

import numpy as np

from droid.brain.db.layouts import FAULT_DEVICE
from droid.subunits.gmf1.encoder_core import EncoderCore, EncoderOut, HomeView, wants_zeroing_fields
from droid.subunits.gmf1.port import PortLink
from droid.subunits.gmf1.quad04 import Quad04Bank
from droid.subunits.gmf1.serial_core import SerialCore, SerialOut, StatusView, snapshot_command


def _fault_bits(v, on: bool, was_on: bool) -> None:
    f = int(v["fault"])
    if on:
        v["fault"] = f | FAULT_DEVICE
    elif was_on:
        v["fault"] = f & ~FAULT_DEVICE


class SerialStation:
    """droid-gmf1-serial's cycle, once per relayed heartbeat tick."""

    def __init__(self, core: SerialCore, link: PortLink, ctrl_command, ctrl_status, gate=None) -> None:
        self.core = core
        self.gate = gate  # a droid.guard.gate.GuardGate where the cell declares a guard (its stale rule)
        self.link = link
        self.ctrl_command = ctrl_command
        self.ctrl_status = ctrl_status
        self._fault_was = False
        self._busy_written: int | None = None  # the last busy-only write (skipped when it repeats)
        self.last: SerialOut | None = None

    def cycle(self, tick: int) -> SerialOut:
        rec = self.ctrl_command.read()
        st = self.ctrl_status.read()
        if self.gate is not None:  # FAULT_GUARD while the collision guard is silent (the KAREL halts)
            self.gate.apply(rec, st, tick, self.ctrl_status)
        cmd = snapshot_command(rec)
        view = StatusView(bool(int(st["homed"])), np.array(st["encoder_pos"], np.int64), int(st["cmd_id"]),
                          int(st["fault"]))
        rx = self.link.read()
        out = self.core.step(tick, cmd, view, rx, self.link.is_open)
        if out.close_port:
            self.link.close()
        if out.tx:
            self.link.write(out.tx)
        if out.open_port:
            self.link.open()
        busy_only = set(out.fields) == {"busy"}
        repeat = busy_only and out.fields["busy"] == self._busy_written and not out.fault and not self._fault_was
        if not repeat:  # an idle tick with nothing new costs no lock
            with self.ctrl_status.locked() as v:
                for k, val in out.fields.items():
                    v[k] = val
                _fault_bits(v, out.fault, self._fault_was)
                self.ctrl_status.mark_written()
            self._busy_written = out.fields["busy"] if busy_only else None
        self._fault_was = out.fault
        self.last = out
        return out


class EncoderStation:
    """droid-gmf1-encoder's cycle at 120 Hz; ``bank`` is a Quad04Bank (or None while the cards are missing)."""

    def __init__(self, core: EncoderCore, ctrl_status) -> None:
        self.core = core
        self.ctrl_status = ctrl_status
        self._fault_was = False
        self.refreshes = 0
        self._rest: tuple | None = None  # (the bank, its registers' bytes, the homing fields) of the last cycle

    def cycle(self, bank, now_ns: int) -> EncoderOut | None:
        """Read the cards, step the core, write Status.  Exceptions of ``bank`` propagate (the shell
        reopens); call :meth:`fault` instead while there is no bank.

        The rest path (issue 44): the same cards' registers, byte for byte, and the same homing
        fields as the last cycle, whose step can repeat (EncoderCore.repeatable), with no zeroing
        wanted: the core's :meth:`~EncoderCore.repeat` -- what its step would return -- without
        reading the counters; the same writes."""
        core = self.core
        regs = bank.channel_bytes() if type(bank) is Quad04Bank else None  # one read of the cards
        if regs is None:
            raw, done = bank.read_joints()
        with self.ctrl_status.locked() as v:
            fields = (int(v["cmd_mode"]), int(v["busy"]), int(v["cmd_result"]), int(v["homed"]))
            rest = self._rest
            if (regs is not None and rest is not None and rest[0] is bank and rest[1] == regs and rest[2] == fields
                    and core.repeatable and not wants_zeroing_fields(*fields)):
                out = core.repeat()
            else:
                if regs is not None:
                    raw, done = Quad04Bank.joints_from(regs)
                out = core.step(raw, done, HomeView(*fields))
            for k, val in out.fields.items():
                v[k] = val
            v["updated_ns"] = now_ns
            _fault_bits(v, out.fault, self._fault_was)
            self.ctrl_status.mark_written()
        self._fault_was = out.fault
        self.refreshes += 1
        self._rest = (bank, regs, fields) if regs is not None else None
        if out.reset:
            bank.reset_joints()
        return out

    def fault(self) -> None:
        """No readable cards this cycle: assert FAULT_DEVICE; the pose goes stale (updated_ns stops)."""
        with self.ctrl_status.locked() as v:
            _fault_bits(v, True, self._fault_was)
            self.ctrl_status.mark_written()
        self._fault_was = True
