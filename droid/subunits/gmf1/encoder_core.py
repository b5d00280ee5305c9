"""The core of droid-gmf1-encoder (thesis §4.2.5): encoder counters -> joint angles -> FK -> Status.

Thesis: "The Encoder program is device driver/server which initializes the 2
ISA encoder boards and reads the contents of each encoder register at a rate
of 120Hz.  Each joint encoder count is then mapped into a joint angle which
follows the Denavit-Hartenberg convention.  Using a forward kinematic model,
the 6 joint angles are converted into a transformation matrix which is placed
into the status memory area."

:class:`EncoderCore` does one cycle from plain inputs: the six 24-bit counter
readings [counts], the cards' command counters, and the Status fields the
homing handshake needs.  It returns the Status fields to write and whether the
counters must be reset.

* The 24-bit counters are extended to unbounded counts
  (:func:`droid.kinematics.extend_counters`); the first reading is taken as a
  signed 24-bit value.
* ``encoder_pos`` [counts] is written every cycle.  It is relative to home
  once homed, to the power-up counter values before.
* x, y, z [mm] and R of the wrist centre in the GLOBAL frame (the model
  carries the subunit's base pose) are written only while homed — before
  homing the counts mean nothing (the remote does the same, §4.1.8).
* Homing (droid-home, docs/gmf1.md): droid-gmf1-serial sends ``HOME`` and
  clears ``homed``; when the controller reports DONE it sets ``busy = 0`` with
  ``cmd_mode = HOME_MODE`` and ``cmd_result = CMD_OK``.  Seeing exactly that
  with ``homed == 0``, this core asks the cards to RESET every joint counter;
  when all six channels have executed it (their DONE counters moved) the
  counts restart from 0 at the home pose and ``homed = 1``.  No answer within
  ``reset_timeout_s`` is a device fault; the reset is retried after
  ``retry_s``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from droid.brain.db.layouts import CMD_OK, HOMED, HOME_MODE
from droid.kinematics import RobotModel, extend_counters
from droid.subunits.gmf1.quad04_map import COUNTER_BITS

_I32_MIN, _I32_MAX = -(1 << 31), (1 << 31) - 1


@dataclass(frozen=True)
class HomeView:
    """The Status fields of the homing handshake."""

    cmd_mode: int
    busy: int
    cmd_result: int
    homed: int


@dataclass
class EncoderOut:
    fields: dict = field(default_factory=dict)  # Status fields to write
    reset: bool = False  # ask the cards to RESET every joint counter
    fault: bool = False  # FAULT_DEVICE level (a reset the cards did not execute)


def signed24(raw) -> np.ndarray:
    """24-bit counter values -> signed counts [counts] (int64)."""
    r = np.asarray(raw, np.int64) & ((1 << COUNTER_BITS) - 1)
    return np.where(r >= 1 << (COUNTER_BITS - 1), r - (1 << COUNTER_BITS), r)


def _as_list(raw) -> list:
    return raw.tolist() if isinstance(raw, np.ndarray) else [int(x) for x in raw]


def wants_zeroing(h: HomeView) -> bool:
    """True when the serial program reports a finished HOME and the counters are not yet zeroed."""
    return h.cmd_mode == HOME_MODE and h.busy == 0 and h.cmd_result == CMD_OK and h.homed != HOMED


def wants_zeroing_fields(cmd_mode: int, busy: int, cmd_result: int, homed: int) -> bool:
    """:func:`wants_zeroing` of the four fields (without a HomeView)."""
    return cmd_mode == HOME_MODE and busy == 0 and cmd_result == CMD_OK and homed != HOMED


class EncoderCore:
    """One encoder cycle; see the module docstring.  ``model`` includes the subunit's base pose."""

    def __init__(self, model: RobotModel, rate_hz: float = 120.0, reset_timeout_s: float = 0.5,
                 retry_s: float = 1.0) -> None:
        self.model = model
        self.rate_hz = rate_hz
        self.reset_timeout = max(1, math.ceil(reset_timeout_s * rate_hz))
        self.retry = max(1, math.ceil(retry_s * rate_hz))
        self.extended: np.ndarray | None = None
        self.zeroing: tuple[np.ndarray, int] | None = None  # (DONE counters before, cycle asked)
        self.retry_at = 0
        self.cycle = 0
        self.fault = False
        self.resets = 0
        self.homings = 0
        self._fk_key: bytes | None = None  # the counts of the last FK, and its Status fields
        self._fk_fields: dict = {}
        self._still: tuple | None = None  # (raw, homed, fields) of the last cycle that can repeat

    def restart(self) -> None:
        """The cards were replaced (re-opened onto another object): forget the counter history."""
        self.extended = None
        self.zeroing = None
        self._still = None

    @property
    def repeatable(self) -> bool:
        """The last cycle can repeat: a :meth:`step` on the same counters, with the same homing
        fields and no zeroing wanted, takes the path of an arm at rest (:meth:`repeat`)."""
        return self._still is not None and self.zeroing is None

    def repeat(self) -> EncoderOut:
        """:meth:`step` of the last cycle's counters and homing fields when :attr:`repeatable` and
        no zeroing is wanted: its rest path, without the readings (EncoderStation's rest path)."""
        self.cycle += 1
        out = EncoderOut()
        out.fields.update(self._still[2])
        out.fault = self.fault
        return out

    def step(self, raw, done, home: HomeView) -> EncoderOut:
        """One cycle: ``raw`` six 24-bit counters [counts], ``done`` their cards' DONE counters."""
        self.cycle += 1
        out = EncoderOut()
        still = self._still
        if still is not None and self.zeroing is None and not wants_zeroing(home):
            # an arm at rest (the holder of a trial): the same counters as the last cycle extend
            # to the same counts -- the same fields, without the numpy work (issue 13 item 6)
            if _as_list(raw) == still[0] and (int(home.homed) == HOMED) == still[1]:
                out.fields.update(still[2])
                out.fault = self.fault
                return out
        raw_in = raw
        raw = np.asarray(raw, np.int64)
        done = np.asarray(done, np.int64)
        if self.extended is None:
            self.extended = signed24(raw)
        else:
            self.extended = extend_counters(self.extended, raw, COUNTER_BITS)
        homed = int(home.homed) == HOMED
        if self.zeroing is not None:
            before, asked = self.zeroing
            if np.all(done != before):
                self.extended = signed24(raw)  # counting from 0 at the home pose
                self.zeroing = None
                self.fault = False
                self.homings += 1
                homed = True
                out.fields["homed"] = HOMED
            elif self.cycle - asked > self.reset_timeout:
                self.zeroing = None
                self.fault = True
                self.retry_at = self.cycle + self.retry
        elif wants_zeroing(home) and self.cycle >= self.retry_at:
            self.zeroing = (done.copy(), self.cycle)
            self.resets += 1
            out.reset = True
        pos = np.clip(self.extended, _I32_MIN, _I32_MAX).astype(np.int32)
        out.fields["encoder_pos"] = pos
        if homed and self.zeroing is None:
            key = pos.tobytes()
            if key != self._fk_key:  # the FK of unchanged counts is the last one (an arm at rest)
                T = self.model.fk(self.model.gearing.counts_to_joints(pos.astype(float)))
                self._fk_key, self._fk_fields = key, dict(x=T[0, 3], y=T[1, 3], z=T[2, 3], R=T[:3, :3])
            out.fields.update(self._fk_fields)
        out.fault = self.fault
        repeatable = self.zeroing is None and not out.reset and "homed" not in out.fields
        self._still = (_as_list(raw_in), homed, dict(out.fields)) if repeatable else None
        return out
