"""droid-guard's station: the guard's cycle on a heartbeat tick over the arms' records (issue 41).

:class:`GuardStation` reads every arm's Brain Status (``encoder_pos``: the measured joints,
``encoder_cmd``: the way-point its planner sends next; counts through the arm's gearing to deg),
runs :class:`~droid.guard.core.GuardCore` and writes FAULT_COLLISION into every arm's own Status
(its controller ``ctrl_status``, as droid-ft's guard writes FAULT_FORCE: the arm's planner ends
the move and refuses NORMAL moves while it is set) when the protective stop trips, clearing it
on :meth:`release`.  Its own Status is :attr:`status` (docs/guard.md): least distance [mm], the
closest pair, the override per arm, state, the cycle time [us], trips.

The same station runs in lockstep (:func:`attach_lockstep`: on the scheduler's tick after the
arms' stations) and in the live program (not yet written: docs/guard.md, "Not done").
"""
from __future__ import annotations

import time

import numpy as np

from droid.brain.layouts import FAULT_COLLISION
from droid.guard.cell import guard_scene, guard_table
from droid.guard.core import GuardCore, GuardVerdict
from droid.guard.ssm import ssm_params

#: the guard's place on a lockstep tick: after the arms' stations (ORDER_HEARTBEAT = 20), before tasks (30)
ORDER_GUARD = 25


def set_collision_fault(ctrl_status, on: bool) -> None:
    """FAULT_COLLISION in an arm's own Status (its other bits kept)."""
    with ctrl_status.locked() as st:
        st["fault"] = (int(st["fault"]) & ~FAULT_COLLISION) | (FAULT_COLLISION if on else 0)
        ctrl_status.mark_written()


class GuardStation:
    """The guard over arms ``{name: (gearing, brain_status, ctrl_status)}`` (see the module docstring)."""

    def __init__(self, core: GuardCore, arms: dict) -> None:
        self.core, self.arms = core, arms
        self.enabled = True
        self.faulted = False
        self.status: dict = {"state": "clear", "distance_mm": float("inf"), "pair": ("", ""), "override": {},
                             "cycle_us": 0.0, "trips": 0, "tick": 0}
        self.last: GuardVerdict | None = None

    def joints(self) -> tuple[dict, dict]:
        """Measured and commanded joints [deg] of every arm from its Brain Status."""
        meas, cmd = {}, {}
        for name, (gearing, brain_status, _) in self.arms.items():
            st = brain_status.read()
            meas[name] = gearing.counts_to_joints(np.asarray(st["encoder_pos"], float))
            cmd[name] = gearing.counts_to_joints(np.asarray(st["encoder_cmd"], float))
        return meas, cmd

    def on_tick(self, tick: int) -> None:
        if not self.enabled:
            return
        t0 = time.perf_counter_ns()
        v = self.core.step(*self.joints())
        if v.stop != self.faulted:
            for _, _, ctrl_status in self.arms.values():
                set_collision_fault(ctrl_status, v.stop)
            self.faulted = v.stop
        self.last = v
        self.status.update(state=v.state, distance_mm=v.distance_mm, pair=v.pair, override=dict(v.override),
                           closing_mm_s=v.closing_mm_s, separation_mm=v.separation_mm, trips=self.core.trips,
                           tick=tick, cycle_us=(time.perf_counter_ns() - t0) / 1000.0)

    def release(self) -> None:
        """End the protective stop: the latch and every arm's FAULT_COLLISION."""
        self.core.release()
        for _, _, ctrl_status in self.arms.values():
            set_collision_fault(ctrl_status, False)
        self.faulted = False


def guard_core(cell, scene=None) -> GuardCore:
    """The cell's guard core: its scene and its ``[guard] ssm`` terms at its heartbeat."""
    scene = guard_scene(cell) if scene is None else scene
    return GuardCore(scene, ssm_params(guard_table(cell).get("ssm"), str(cell.path)), 1.0 / cell.heartbeat_hz)


def attach_lockstep(sched, cell, subunits: dict, scene=None) -> GuardStation:
    """A :class:`GuardStation` on a lockstep scheduler over the built arms ``subunits`` (name ->
    LockstepSubunit whose ``parts`` has ``model`` and ``ctrl_status``), ticking after the arms."""
    core = guard_core(cell, scene)
    arms = {}
    for name in core.scene.arms:
        parts = subunits[name].parts
        arms[name] = (parts.model.gearing, subunits[name].status, parts.ctrl_status)
    station = GuardStation(core, arms)
    sched.on_tick(station.on_tick, "droid-guard", order=ORDER_GUARD)
    return station
