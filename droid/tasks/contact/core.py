"""A force-controlled task: touch a surface, then slide along it holding the normal force
(issue 27 item 5; thesis §7.3: "force control ... through the standard interface").

An admittance controller on the arm's cartesian commands.  Each cycle (every
``cycle_ticks`` heartbeat ticks, T = cycle_ticks / heartbeat_hz seconds) it reads the
wrist F/T sensor's Status (the normal force F = -f_x of ``force_tool_N``: the tool frame's
x is the tool axis toward the surface, so the surface pushes along -x) and the arm's, and
writes one cartesian command of the wrist centre:

* **approach**: the commanded tool point moves along the tool axis at
  ``approach_speed_mm_s`` until F crosses ``touch_n`` (none within ``approach_max_mm``:
  stop ``no contact``);
* **settle**: ``settle_s`` in place, the normal loop on;
* **path**: the commanded tool point moves along the tool's travel axis (z) at ``speed``
  [mm/s] for ``length_mm``, and along the tool axis by the admittance law::

      x[k+1] = x[k] + K (F_set - F[k]) T            (x: depth along the tool axis [mm])

On a contact of stiffness k [N/mm] (F = k x, the arm stiff) the force error obeys
e[k+1] = (1 - K k T) e[k]: stable for **K k T < 2** (and without overshoot for K k T < 1).
The gains file names the stiffest contact it must hold (``contact_stiffness_n_per_mm``);
:func:`load_gains` refuses gains past the limit in one line.  The arm's drives and the
commands' lag (one cycle of interpolation, the servo's tracking) soften the contact and
delay the loop: the shipped gains keep K k T = 0.33 for that margin.

Stops, each with a reason: ``end`` (the path is done), ``over-force`` (F > ``force_max_n``,
checked at every tick, between cycles too),
``contact lost`` (F < ``contact_lost_n`` for ``lost_cycles`` path cycles), ``no contact``,
``ft stale`` (the F/T Status stale or not valid), ``arm fault`` (the arm's fault bits),
``arm stale`` (the arm's Status stale for the stale grace).

:class:`ContactStation` is the task as a station (docs/design.md §11, like
droid.tasks.seam.station.SeamtrackStation): a tick's records in, the tick's command out,
so a real-time shell can run it as the lockstep trial does (droid.experiments.contact_trial).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from droid.brain.db.layouts import FAULTS_STOP_RUN, fault_names
from droid.cli import BadInput, read_toml
from droid.kinematics.transforms import inv_homo, record_pose
from droid.numbers import NumberError, check_numbers

BUNDLED_GAINS = Path(__file__).parent / "gains.toml"
#: The admittance loop's stability limit: K k T < STABILITY_LIMIT (module docstring).
STABILITY_LIMIT = 2.0
STALE_GRACE_S = 2.0  # as droid.tasks.seam.station: an arm's Status stale this long ends the run

STOP_END, STOP_OVERFORCE, STOP_LOST, STOP_NO_CONTACT = "end", "over-force", "contact lost", "no contact"
STOP_FT_STALE, STOP_ARM_FAULT, STOP_ARM_STALE = "ft stale", "arm fault", "arm stale"
PHASES = ("approach", "settle", "path", "done")


# Alike in shape only to other numeric dataclasses (contact_trial's ContactTrialConfig): the controller's gains.
@dataclass(frozen=True)
class Gains:
    """The controller's numbers (gains.toml; module docstring)."""

    admittance_mm_per_n_s: float = 0.5
    contact_stiffness_n_per_mm: float = 20.0
    cycle_ticks: int = 2
    touch_n: float = 5.0
    approach_speed_mm_s: float = 5.0
    approach_max_mm: float = 30.0
    force_max_n: float = 60.0
    contact_lost_n: float = 2.0
    lost_cycles: int = 3
    settle_s: float = 1.0

    def loop_gain(self, heartbeat_hz: float) -> float:
        """K k T of the admittance loop on the stiffest contact (stable below 2)."""
        return self.admittance_mm_per_n_s * self.contact_stiffness_n_per_mm * self.cycle_ticks / heartbeat_hz

    def check(self, heartbeat_hz: float, source: str = "gains") -> "Gains":
        """Refuse gains past the stability limit (BadInput: one line)."""
        g = self.loop_gain(heartbeat_hz)
        if not g < STABILITY_LIMIT:
            raise BadInput(f"{source}: admittance_mm_per_n_s {self.admittance_mm_per_n_s:g} x "
                           f"contact_stiffness_n_per_mm {self.contact_stiffness_n_per_mm:g} x T "
                           f"{self.cycle_ticks / heartbeat_hz:g} s = {g:.3g}: the loop is unstable at K k T >= 2")
        return self


def load_gains(path: str | os.PathLike | None = None, heartbeat_hz: float = 60.0) -> Gains:
    """The gains file (default: the bundled one), every number range-checked, the stability
    limit checked at ``heartbeat_hz``; BadInput (one line) otherwise."""
    src = str(path or BUNDLED_GAINS)
    data = read_toml(src, "gains")
    names = {f.name for f in fields(Gains)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise BadInput(f"gains {src}: unknown key {unknown[0]!r}")
    try:
        check_numbers(data)
    except NumberError as exc:
        raise BadInput(f"gains {src}: {exc}") from None
    kinds = {f.name: f.type for f in fields(Gains)}
    for key, value in data.items():
        integral = kinds[key] in ("int", int)
        if isinstance(value, bool) or not isinstance(value, int if integral else (int, float)):
            raise BadInput(f"gains {src}: {key} = {value!r}: must be {'an integer' if integral else 'a number'}")
    data = {k: (v if kinds[k] in ("int", int) else float(v)) for k, v in data.items()}
    return Gains(**data).check(heartbeat_hz, f"gains {src}")


@dataclass(frozen=True)
class ArmStatus:
    """The arm's Status at a tick: the global wrist-centre pose (4x4, mm), fault bits, stale."""

    tick: int
    pose: np.ndarray
    fault: int = 0
    stale: bool = False

    @classmethod
    def of_record(cls, rec) -> "ArmStatus":
        """The arm's Status record as the station judges it, in both runners: its pose, its
        stale flag and only the fault bits that stop a press (``FAULTS_STOP_RUN``: a fault the
        arm cannot move with, or a protective stop -- braking, collision); a clamped joint
        target or a silent link shows in the Status but is not the press's stop."""
        return cls(int(rec["tick"]), record_pose(rec), int(rec["fault"]) & FAULTS_STOP_RUN, bool(int(rec["stale"])))


@dataclass(frozen=True)
class FtStatus:
    """The F/T sensor's Status at a tick (droid-ft's ``ft6_status``): the wrench on the tool in
    the tool frame [N], ``valid`` and ``stale`` as droid-ft writes them."""

    force_tool_N: np.ndarray
    valid: bool = True
    stale: bool = False

    @property
    def normal_n(self) -> float:
        """The surface's push on the tool along -x_tool [N] (positive when pressing)."""
        return -float(self.force_tool_N[0])


@dataclass
class ContactOutput:
    """One tick's result: the command (the WCP pose, 4x4, for ``ticks`` ticks) or None; the stop."""

    cmd: np.ndarray | None = None
    ticks: int = 0
    stop: str | None = None
    detail: str = ""
    cycle: bool = False  # a cycle ran at this tick (the trial logs it)


class ContactStation:
    """Touch, settle, slide (module docstring).  ``T_wcp_tool``: the tool point on the wrist
    centre (4x4, mm); ``force_n`` the normal force to hold [N]; ``speed_mm_s``, ``length_mm``
    the path along the tool's z axis."""

    def __init__(self, gains: Gains, heartbeat_hz: float, T_wcp_tool, force_n: float, speed_mm_s: float,
                 length_mm: float) -> None:
        self.gains = gains.check(heartbeat_hz)
        if not 0.0 < force_n < gains.force_max_n:
            raise BadInput(f"force {force_n:g} N: must be in (0, force_max_n {gains.force_max_n:g}) N")
        self.T_wcp_tool = np.asarray(T_wcp_tool, float)
        self.T_tool_wcp = inv_homo(self.T_wcp_tool)
        self.force_n = float(force_n)
        self.speed_mm_s = float(speed_mm_s)
        self.length_mm = float(length_mm)
        self.T = gains.cycle_ticks / heartbeat_hz  # the cycle [s]
        self.stale_grace_ticks = max(1, round(STALE_GRACE_S * heartbeat_hz))
        self.settle_cycles = max(0, round(gains.settle_s / self.T))
        self.phase = "approach"
        self.T0: np.ndarray | None = None  # the tool frame where the task started (global)
        self.depth_mm = 0.0  # commanded tool point along the tool axis from T0 [mm]
        self.along_mm = 0.0  # commanded travel along the tool's z from T0 [mm]
        self.cycles = 0
        self.next_tick: int | None = None
        self.lost = 0
        self.settled = 0
        self.stale_since: int | None = None
        self.done: str | None = None
        self.detail = ""
        self.last_force_n = math.nan

    def _stop(self, why: str, detail: str = "") -> ContactOutput:
        self.done, self.detail, self.phase = why, detail, "done"
        return ContactOutput(stop=why, detail=detail, cycle=True)

    def command_pose(self) -> np.ndarray:
        """The commanded WCP pose (global, 4x4, mm) for the present depth and travel."""
        T = self.T0.copy()
        T[:3, 3] = self.T0[:3, 3] + self.depth_mm * self.T0[:3, 0] + self.along_mm * self.T0[:3, 2]
        return T @ self.T_tool_wcp

    def on_tick(self, tick: int, arm: ArmStatus, ft: FtStatus) -> ContactOutput:
        """One heartbeat tick: when a cycle is due, check the records and step the controller."""
        if self.done is not None:
            return ContactOutput(stop=self.done, detail=self.detail)
        if self.next_tick is not None and tick < self.next_tick:
            # over-force is checked every tick, not only on cycles: the stop comes a cycle sooner
            if not ft.stale and ft.valid and ft.normal_n > self.gains.force_max_n:
                self.last_force_n = ft.normal_n
                return self._stop(STOP_OVERFORCE, f"normal force {ft.normal_n:.1f} N > {self.gains.force_max_n:g} N")
            return ContactOutput()
        self.next_tick = tick + self.gains.cycle_ticks
        g = self.gains
        if arm.fault:
            return self._stop(STOP_ARM_FAULT, f"fault bits {arm.fault:#x}: {', '.join(fault_names(arm.fault))}")
        if arm.stale:
            if self.stale_since is None:
                self.stale_since = tick
            if tick - self.stale_since > self.stale_grace_ticks:
                return self._stop(STOP_ARM_STALE, "the arm's Status went stale")
            return ContactOutput(cycle=True)  # no command: the arm finishes its last step and waits
        self.stale_since = None
        if ft.stale or not ft.valid:
            return self._stop(STOP_FT_STALE, "the F/T Status is stale or not valid")
        f = ft.normal_n
        self.last_force_n = f
        if self.T0 is None:
            self.T0 = np.asarray(arm.pose, float) @ self.T_wcp_tool
        self.cycles += 1
        if f > g.force_max_n:
            return self._stop(STOP_OVERFORCE, f"normal force {f:.1f} N > {g.force_max_n:g} N")
        T = self.T
        if self.phase == "approach":
            if f >= g.touch_n:
                self.phase = "settle"
            else:
                self.depth_mm += g.approach_speed_mm_s * T
                if self.depth_mm > g.approach_max_mm:
                    return self._stop(STOP_NO_CONTACT, f"no touch within {g.approach_max_mm:g} mm")
        if self.phase in ("settle", "path"):
            self.depth_mm += g.admittance_mm_per_n_s * (self.force_n - f) * T
        if self.phase == "settle":
            self.settled += 1
            if self.settled >= self.settle_cycles:
                self.phase = "path"
        elif self.phase == "path":
            if f < g.contact_lost_n:
                self.lost += 1
                if self.lost >= g.lost_cycles:
                    return self._stop(STOP_LOST, f"normal force {f:.2f} N < {g.contact_lost_n:g} N "
                                                 f"for {self.lost} cycles")
            else:
                self.lost = 0
            if self.along_mm >= self.length_mm:
                return self._stop(STOP_END, f"{self.length_mm:g} mm done")
            self.along_mm = min(self.length_mm, self.along_mm + self.speed_mm_s * T)
        return ContactOutput(cmd=self.command_pose(), ticks=g.cycle_ticks, cycle=True)
