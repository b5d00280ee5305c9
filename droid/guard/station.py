"""droid-guard's station: the guard's cycle on a heartbeat tick over the arms' records (issue 41).

:class:`GuardStation` reads every arm's Brain Status (``encoder_pos``: the measured joints,
``encoder_cmd``: the way-point its planner sends next; counts through the arm's gearing to deg),
runs :class:`~droid.guard.core.GuardCore` and

* writes FAULT_COLLISION into every arm's own Status (its controller ``ctrl_status``, as
  droid-ft's guard writes FAULT_FORCE: the arm's planner ends the move and refuses NORMAL moves
  while it is set) when the protective stop trips, clearing it on :meth:`release`;
* writes ``guard_tick`` (this tick) and ``guard_override`` (the arm's speed override) into every
  arm's Brain Command (where given): the planners' stale rule and override (droid.guard.gate);
* keeps its own Status, :attr:`status` (a dict) and, where given, the ``guard_status`` record
  (:data:`droid.brain.db.layouts.GUARD_STATUS`, ``/droid.<cell>.guard.status``): least distance
  [mm] and the closest pair, the closing speed and S_p of the pair that decides (the least margin
  d - S_p; at rest the closest pair) and the closest pair's two closest points [mm], the
  override per arm, state, the cycle time [us], trips, the tick; the dict also the deciding
  pair and its distance, the re-zeros seen, the arms not judged (not homed) and the guard's
  notes (:attr:`notes`, each said once: droid-guard logs them).

Disabled (:attr:`enabled` False: a lockstep trial's "guard off") it runs no pass but still
stamps the tick with override 1, so the planners' stale rule holds only for a guard that is gone.

The same station runs in lockstep (:func:`attach_lockstep`: on the scheduler's tick after the
arms' stations) and in the live program (:mod:`droid.guard.live`).
"""
from __future__ import annotations

import time

import numpy as np

from droid.brain.db.layouts import FAULT_COLLISION, GUARD_ARMS, GUARD_STATE_NAMES
from droid.guard.cell import guard_scene, guard_table
from droid.guard.core import GuardCore, GuardVerdict
from droid.guard.gate import DEFAULT_STALE_TICKS, GuardGate, guard_stale_ticks, set_fault_bit
from droid.guard.ssm import ssm_params

#: the guard's place on a lockstep tick: after the arms' stations (ORDER_HEARTBEAT = 20), before tasks (30)
ORDER_GUARD = 25
#: the guard's notes its Status dict keeps (the newest)
NOTES_KEPT = 20
STATE_CODES = {name: code for code, name in GUARD_STATE_NAMES.items()}


def set_collision_fault(ctrl_status, on: bool) -> None:
    """FAULT_COLLISION in an arm's own Status (its other bits kept)."""
    set_fault_bit(ctrl_status, FAULT_COLLISION, on)


def _name(s: str) -> bytes:
    return s.encode()[:16]


class GuardStation:
    """The guard over arms ``{name: (gearing, brain_status, ctrl_status[, brain_command])}`` (see the
    module docstring); ``status_db``: the guard's Status record, or None."""

    def __init__(self, core: GuardCore, arms: dict, status_db=None, stale_ticks: int = DEFAULT_STALE_TICKS,
                 waypoints: set[str] | None = None) -> None:
        if len(arms) > GUARD_ARMS:
            raise ValueError(f"a guard Status holds {GUARD_ARMS} arms, the cell has {len(arms)}")
        self.core, self.arms = core, arms
        #: the arms whose Status ``encoder_cmd`` is a planner's next way-point (None: every arm)
        self.waypoints = None if waypoints is None else set(waypoints)
        self.status_db = status_db
        self.stale_ticks = int(stale_ticks)
        self.enabled = True
        self.faulted = False
        self.cycles = 0
        self.cycle_max_us = 0.0
        self.status: dict = {"state": "clear", "distance_mm": float("inf"), "pair": ("", ""), "override": {},
                             "cycle_us": 0.0, "trips": 0, "tick": 0, "jumps": 0, "unjudged": (), "notes": []}
        #: what the guard said, once each (a re-zero, an arm not homed): droid-guard logs each line
        self.notes: list[str] = []
        self.last: GuardVerdict | None = None
        if status_db is not None:
            with status_db.locked() as r:
                r["n_arms"], r["stale_ticks"], r["pairs"] = len(arms), self.stale_ticks, core.scene.n_pairs
                for i, name in enumerate(arms):
                    r["arms"][i] = _name(name)
                    r["override"][i] = 1.0
                r["a_point_mm"] = r["b_point_mm"] = np.nan
                status_db.mark_written()

    def readings(self) -> tuple[dict, dict, dict, dict, dict]:
        """Every arm's measured and commanded joints [deg] (:meth:`joints`), whether its Status says
        homed, and the tick and the time of its Status (when it was refreshed: a speed is measured
        over the ticks between two refreshes, or the periods between their times when more,
        docs/guard.md §5)."""
        meas, cmd, homed, ticks, stamps = {}, {}, {}, {}, {}
        for name, (gearing, brain_status, *_rest) in self.arms.items():
            st = brain_status.read()
            meas[name], cmd[name] = self._joints_of(name, gearing, st)
            homed[name] = bool(int(st["homed"]))
            ticks[name] = int(st["tick"])
            stamps[name] = int(st["updated_ns"])
        return meas, cmd, homed, ticks, stamps

    def _joints_of(self, name: str, gearing, st) -> tuple[np.ndarray, np.ndarray]:
        q = gearing.counts_to_joints(np.asarray(st["encoder_pos"], float))
        qc = (gearing.counts_to_joints(np.asarray(st["encoder_cmd"], float))
              if self.waypoints is None or name in self.waypoints else q)
        return q, qc

    def joints(self) -> tuple[dict, dict]:
        """Measured and commanded joints [deg] of every arm from its Brain Status.  Only an arm in
        :attr:`waypoints` (a planner sends it one way-point a tick: the Reis, the ABB) has its
        ``encoder_cmd`` taken as the next way-point; for another (the GMF1, whose KAREL
        controller interpolates its own moves) ``encoder_cmd`` is a whole move's target, or
        zeros when idle, and the measured joints stand in for it -- taken as a way-point, a
        target 9-30 deg away one tick ahead read as a closing speed of tens of m/s and stopped
        the live cell on every GMF1 move."""
        meas, cmd = {}, {}
        for name, (gearing, brain_status, *_rest) in self.arms.items():
            meas[name], cmd[name] = self._joints_of(name, gearing, brain_status.read())
        return meas, cmd

    def on_tick(self, tick: int) -> None:
        if not self.enabled:
            self._stamp(tick, {})
            return
        t0 = time.perf_counter_ns()
        v = self.core.step(*self.readings())
        if v.stop != self.faulted:
            for _, _, ctrl_status, *_rest in self.arms.values():
                set_collision_fault(ctrl_status, v.stop)
            self.faulted = v.stop
        self._stamp(tick, v.override)
        self.last = v
        self.cycles += 1
        cycle_us = (time.perf_counter_ns() - t0) / 1000.0
        self.cycle_max_us = max(self.cycle_max_us, cycle_us)
        self.status.update(state=v.state, distance_mm=v.distance_mm, pair=v.pair, override=dict(v.override),
                           closing_mm_s=v.closing_mm_s, separation_mm=v.separation_mm, trips=self.core.trips,
                           tick=tick, cycle_us=cycle_us, ahead_mm=v.ahead_mm, deciding_mm=v.deciding_mm,
                           deciding_pair=v.deciding_pair, jumps=self.core.jumps, unjudged=v.unjudged,
                           points_mm=v.points_mm)
        if v.notes:
            self.notes += v.notes
            del self.notes[:-NOTES_KEPT]
            self.status["notes"] = list(self.notes)
        if self.status_db is not None:
            self._write_status(v, tick, cycle_us)

    def _stamp(self, tick: int, override: dict) -> None:
        """This tick and each arm's override into its Brain Command (the planners read them)."""
        for name, (_, _, _, *command) in self.arms.items():
            if command and command[0] is not None:
                with command[0].locked() as c:
                    c["guard_tick"] = tick
                    c["guard_override"] = override.get(name, 1.0)
                    command[0].mark_written()

    def _write_status(self, v: GuardVerdict, tick: int, cycle_us: float) -> None:
        (a_arm, _, a_body), (b_arm, _, b_body) = (k.partition(".") for k in v.pair)
        with self.status_db.locked() as r:
            r["tick"], r["updated_ns"], r["cycles"] = tick, time.monotonic_ns(), self.cycles
            r["distance_mm"], r["ahead_mm"] = v.distance_mm, v.ahead_mm
            r["closing_mm_s"], r["separation_mm"] = v.closing_mm_s, v.separation_mm
            r["cycle_us"], r["cycle_max_us"] = cycle_us, self.cycle_max_us
            r["state"], r["trips"] = STATE_CODES[v.state], self.core.trips
            r["a_arm"], r["a_body"], r["b_arm"], r["b_body"] = _name(a_arm), _name(a_body), _name(b_arm), _name(b_body)
            r["kernel"] = int(self.core.scene.compiled is not None)
            r["a_point_mm"], r["b_point_mm"] = v.points_mm if v.points_mm is not None else (np.nan, np.nan)
            for i, name in enumerate(self.arms):
                r["override"][i] = v.override.get(name, 1.0)
            self.status_db.mark_written()

    def release(self) -> None:
        """End the protective stop: the latch and every arm's FAULT_COLLISION."""
        self.core.release()
        for _, _, ctrl_status, *_rest in self.arms.values():
            set_collision_fault(ctrl_status, False)
        self.faulted = False


def guard_status_dict(rec) -> dict:
    """A ``guard_status`` record as droid-snoop, droid-record and droid-web show it."""
    n = int(rec["n_arms"])
    text = lambda v: bytes(v).rstrip(b"\0").decode(errors="replace")  # noqa: E731
    arms = [text(rec["arms"][i]) for i in range(n)]
    name = lambda f: text(rec[f])  # noqa: E731
    return {"tick": int(rec["tick"]), "state": GUARD_STATE_NAMES.get(int(rec["state"]), str(int(rec["state"]))),
            "distance_mm": float(rec["distance_mm"]), "ahead_mm": float(rec["ahead_mm"]),
            "pair": [f"{name('a_arm')}.{name('a_body')}", f"{name('b_arm')}.{name('b_body')}"],
            "override": {a: float(rec["override"][i]) for i, a in enumerate(arms)},
            "closing_mm_s": float(rec["closing_mm_s"]), "separation_mm": float(rec["separation_mm"]),
            "cycle_us": float(rec["cycle_us"]), "cycle_max_us": float(rec["cycle_max_us"]),
            "trips": int(rec["trips"]), "cycles": int(rec["cycles"]), "stale_ticks": int(rec["stale_ticks"]),
            "pairs": int(rec["pairs"]), "kernel": int(rec["kernel"]), "points_mm": guard_points(rec)}


def guard_points(rec) -> list[list[float]] | None:
    """The closest pair's two closest points [mm, global frame] of a ``guard_status`` record (on
    body a, on body b), or None where it has none (NaN: nothing judged; a version-1 record)."""
    try:
        a, b = np.asarray(rec["a_point_mm"], float), np.asarray(rec["b_point_mm"], float)
    except (KeyError, ValueError, IndexError):
        return None
    if a.shape != (3,) or b.shape != (3,) or not (np.isfinite(a).all() and np.isfinite(b).all()):
        return None
    return [a.tolist(), b.tolist()]


def guard_core(cell, scene=None) -> GuardCore:
    """The cell's guard core: its scene and its ``[guard] ssm`` terms at its heartbeat."""
    scene = guard_scene(cell) if scene is None else scene
    return GuardCore(scene, ssm_params(guard_table(cell).get("ssm"), str(cell.path)), 1.0 / cell.heartbeat_hz)


def attach_lockstep(sched, cell, subunits: dict, scene=None, status_db=None, gates: bool = True) -> GuardStation:
    """A :class:`GuardStation` on a lockstep scheduler over the built arms ``subunits`` (name ->
    LockstepSubunit whose ``parts`` has ``model`` and ``ctrl_status``), ticking after the arms.
    ``gates``: the arms' planners keep the guard's stale rule and override (as droid-planner does
    in a cell that declares a guard): each arm's ``parts.planner`` (a PlannerStation) or
    the GMF1's ``parts.serial`` (a SerialStation) gets a :class:`~droid.guard.gate.GuardGate`."""
    core = guard_core(cell, scene)
    stale = guard_stale_ticks(cell) or DEFAULT_STALE_TICKS
    arms = {}
    for name in core.scene.arms:
        parts = subunits[name].parts
        arms[name] = (parts.model.gearing, subunits[name].status, parts.ctrl_status, subunits[name].command)
        if gates:
            for station in (getattr(parts, "planner", None), getattr(parts, "serial", None)):
                if station is not None and hasattr(station, "gate"):  # the Reis/ABB planner, the GMF1's serial
                    station.gate = GuardGate(stale)
    waypoints = {n for n in core.scene.arms if getattr(subunits[n].parts, "planner", None) is not None}
    station = GuardStation(core, arms, status_db, stale, waypoints)
    sched.on_tick(station.on_tick, "droid-guard", order=ORDER_GUARD)
    return station
