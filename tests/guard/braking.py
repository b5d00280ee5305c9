"""The Reis servo's braking on the guard's protective stop, in lockstep (issue 41 item 2;
docs/guard.md §5 "Stopping time and distance, measured").

On the held-out cell (tests/guard/cells/overlap_pair.toml: the whole cell, planners, servos and
plant twins) arm1 sweeps joint 1, outstretched, at a share of its ``vmax_deg_s``; halfway through
the move FAULT_COLLISION is set in its own Status, as droid-guard's station sets it on a
protective stop (``set_collision_fault``).  The planner ramps the move down along its path over
``COLLISION_BRAKE_TICKS``, the servo follows, and the servo's own halt recorder
(:class:`droid.subunits.reis.brake_log.BrakeRecorder`, what droid-servo logs as ``halt {json}``)
is fed every 500 Hz servo tick with the servo's state, as droid-servo feeds it.  Measured:

* the **stopping time** T_stop [s]: from the fault's servo tick to the halt record's
  ``standstill_tick`` (the arm's velocity at zero);
* the **stopping distance** D_stop [mm]: the path of the arm's wrist centre (``model.fk``) at the
  plant's *true* joint angles from the fault to the standstill;
* that point's speed v [mm/s] just before the fault.  On a joint-1 sweep every point of the arm
  turns about the same axis, so D_stop / v is the same for any of them (the flange's too).

The guard's S_p counts for each side's travel after its verdict S_r + S_s = v (T_r + T_s / 2)
(``reaction_s`` 0.1 s, ``stop_time_s`` 0.3 s: 0.25 s at v); the effective time
T_eff = D_stop / v is what the servo's braking really takes, to compare with it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from droid.guard.station import set_collision_fault
from droid.sim.lockstep import ORDER_DEVICE
from droid.subunits.reis.brake_log import SERVO_TICK_S, BrakeRecorder
from droid.subunits.reis.device import SERVO_HZ

OUT_DEG = (-50.0, 30.0, 0.0, 20.0, 0.0)  # joints 2-6 of the outstretched arm [deg]
SWEEP_DEG = (-60.0, 60.0)  # joint 1 [deg]
HALT_WAIT_S = 8.0  # the longest wait for the servo's halt record after the stop [s]
QUIET_S = 0.5  # at rest before a sweep: no motion recorded for this long [s]


@dataclass
class Brake:
    share: float  # of vmax_deg_s on joint 1
    joint_deg_s: float  # joint 1's speed [deg/s]
    v_mm_s: float  # the wrist centre's speed just before the fault [mm/s]
    stop_s: float  # T_stop: fault -> standstill (the halt record) [s]
    settle_s: float  # fault -> settled (the halt record) [s]
    stop_mm: float  # D_stop: the wrist centre's path from the fault to standstill [mm]
    starved: bool  # the servo's queue ran dry (its emergency braking profile) during the halt
    peak_counts_per_tick: int

    @property
    def t_eff_s(self) -> float:
        return self.stop_mm / self.v_mm_s

    def line(self) -> str:
        return (f"{self.share:.2f} vmax ({self.joint_deg_s:.0f} deg/s): v {self.v_mm_s:.0f} mm/s, T_stop "
                f"{self.stop_s * 1e3:.0f} ms (settled {self.settle_s * 1e3:.0f} ms), D_stop {self.stop_mm:.1f} mm, "
                f"T_eff {self.t_eff_s * 1e3:.0f} ms{', starved' if self.starved else ''}")


class BrakeTap:
    """The servo's halt recorder fed on every servo tick of a lockstep arm, as droid-servo feeds it,
    with the plant's true joints [deg] kept per servo tick."""

    def __init__(self, sched, arm, name: str) -> None:
        self.arm = arm
        self.rec = BrakeRecorder()
        self.events = []
        self.true: dict[int, np.ndarray] = {}
        self._arrived = False
        take = arm.servo_station.take

        def counted(msg, _take=take):  # whether a command arrived this servo tick (droid-servo's ``arrived``)
            got = _take(msg)
            self._arrived = self._arrived or got
            return got

        arm.servo_station.take = counted
        sched.every(SERVO_HZ, self._tick, f"{name}.brake-tap", order=ORDER_DEVICE + 1)

    def _tick(self, t_ns: int) -> None:
        core = self.arm.servo
        ev = self.rec.step(core.tick, self._arrived, core.starved, core.encoder_pos, core.homing)
        self._arrived = False
        self.true[core.tick] = self.arm.plant.joint_deg.copy()
        if ev is not None:
            self.events.append(ev)


def wcp_mm(model, q_deg) -> np.ndarray:
    """The wrist centre [mm, global] at joints ``q_deg``."""
    return np.asarray(model.fk(np.asarray(q_deg, float)))[:3, 3]


def measure(r, tap: BrakeTap, share: float) -> Brake:
    """One sweep of arm1's joint 1 at ``share`` of its vmax, stopped halfway (see the module docstring)."""
    parts = r.lc.subunits["arm1"].parts
    model = parts.model
    arm = r.arm("arm1")
    a, b = np.array([SWEEP_DEG[0], *OUT_DEG]), np.array([SWEEP_DEG[1], *OUT_DEG])
    speed = share * float(model.vmax_deg_s[0])
    # back to the start at a slow pace, then the sweep
    ph = r.move_joint("arm1", a, max(2.0, abs(float(r.joints("arm1")[0]) - a[0]) / 30.0), "arm1 to the sweep's start")
    assert ph.ok, ph.line()
    # at rest first: the recorder's halt of that move complete (a motion begun against the direction
    # of the last one before its halt settled would read as that halt's pull-back, not as a motion)
    # (and its links' spring-back over: no motion recorded for QUIET_S)
    servo = parts.servo
    for _ in range(int(HALT_WAIT_S / 0.25)):
        last = tap.events[-1].settled_tick if tap.events else -1
        if not tap.rec._moving and servo.tick - last >= QUIET_S * SERVO_HZ:
            break
        r.sched.run_for(0.25)
    seconds = (b[0] - a[0]) / speed
    counts = np.rint(model.gearing.joints_to_counts(b)).astype(int)
    n0 = len(tap.events)
    arm.command_joint(counts, arm.ticks_for(seconds))
    r.sched.run_for(seconds / 2.0)
    k = parts.servo.tick
    v = float(np.linalg.norm(wcp_mm(model, tap.true[k]) - wcp_mm(model, tap.true[k - 5]))) / (5 * SERVO_TICK_S)
    set_collision_fault(parts.ctrl_status, True)  # what droid-guard's station writes on a protective stop
    new: list = []
    for _ in range(int(HALT_WAIT_S / 0.25)):  # until the servo records the halt (its settling is slow)
        r.sched.run_for(0.25)
        new = [e for e in tap.events[n0:] if e.moving_tick >= k]
        if new:
            break
    set_collision_fault(parts.ctrl_status, False)
    # the halt; a second, tiny record may follow it: the compliant links' spring-back nudging the
    # motors a few counts (tests/faults/test_brake_log.py), not the braking
    assert new and new[0].peak_speed_counts_per_tick > 10, f"no halt of the sweep after servo tick {k}: {tap.events[n0:]}"
    ev = new[0]
    path = np.array([wcp_mm(model, tap.true[t]) for t in range(k, ev.standstill_tick + 1)])
    stop_mm = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    return Brake(share, speed, v, (ev.standstill_tick - k) * SERVO_TICK_S, (ev.settled_tick - k) * SERVO_TICK_S,
                 stop_mm, ev.starved_tick >= 0, ev.peak_speed_counts_per_tick)
