"""The README demo's motions in lockstep with the live guard on (issue 41; docs/guard.md §9).

A shipped cell built whole in lockstep (droid.sim.lockstep_cell: every subunit, the cell's own
world) with droid-guard's station on the scheduler and a gate on every arm's planner (or the
GMF1's serial program) -- ``attach_lockstep(..., gates=True)``, as ``[guard] run = true`` gives a
live cell -- from the first tick.  Then what ``scripts/demo.sh`` does, through the arms' Brain
Commands as droid-home, droid-move and droid-seamtrack write them:

* :meth:`DemoRun.home`: droid-home, one arm after the other (the welder, then the holder);
* :meth:`DemoRun.move_to_start`: a straight cartesian move of the wrist centre (droid-seamtrack's
  ``move_to_start`` in a cell without a ``[guard]`` table; with one it takes
  droid.tasks.seamtrack.start_route's joint moves, :meth:`DemoRun.move_joint`) in max(3 s, 1.5 x
  the slowest joint at its limit), the holder to the holding pose of the position, then the
  welder to the start;
* :meth:`DemoRun.move_joint`: a joint move (droid-move ARM joint ...);
* :meth:`DemoRun.track`: droid-seamtrack's tracking (its station, droid.tasks.seam.station, on
  the Brain Status of both arms and the lead sensor, its commands into the Brain Commands).

Every tick after the guard's the run records its verdict; :class:`Phase` sums each step up: the
least distance, the largest S_p, the closing speeds, the least override, the trips, the states.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from droid.brain.cell.cell_layout import layout_for_cell
from droid.brain.cell.cellfile import BUNDLED_CELLS, load_cell
from droid.guard.station import ORDER_GUARD, attach_lockstep
from droid.sim.lockstep import ORDER_TASK
from droid.sim.lockstep_cell import build_lockstep_cell
from droid.tasks.seamtrack import START_MOVE_MARGIN, START_MOVE_MIN_S  # droid-seamtrack's start moves



@dataclass
class Phase:
    """The guard's verdicts over one step of the demo."""

    name: str
    ok: bool = False  # the step did what it should (homed; the move done; the track's end reached)
    detail: str = ""
    ticks: int = 0
    least_mm: float = math.inf  # the least distance of any judged pair
    least_pair: tuple = ("", "")
    max_sp_mm: float = 0.0  # the largest S_p of the deciding pair
    max_closing_mm_s: float = 0.0  # the largest closing speed of the deciding pair
    closing_at_least: float = 0.0  # the deciding pair's closing speed at the least distance
    min_override: float = 1.0
    trips: int = 0
    trip: tuple | None = None  # at the first trip: (distance [mm], pair, closing [mm/s], S_p [mm])
    states: Counter = field(default_factory=Counter)

    def line(self) -> str:
        return (f"{self.name}: {'ok' if self.ok else 'FAILED'} {self.detail}; least {self.least_mm:.1f} mm "
                f"({' with '.join(self.least_pair)}), S_p at most {self.max_sp_mm:.1f} mm, closing at most "
                f"{self.max_closing_mm_s:.0f} mm/s, least override {self.min_override:.2f}, trips {self.trips}"
                + (f" (the first at {self.trip[0]:.1f} mm, {' with '.join(self.trip[1])}, closing "
                   f"{self.trip[2]:.0f} mm/s, S_p {self.trip[3]:.1f} mm)" if self.trip else "") + f", {dict(self.states)}")


class DemoRun:
    """One shipped cell in lockstep with the guard on (see the module docstring)."""

    def __init__(self, cell_name: str, position: str = "i") -> None:
        self.cell = load_cell(BUNDLED_CELLS / cell_name)
        self.lc = build_lockstep_cell(self.cell)
        self.guard = attach_lockstep(self.lc.sched, self.cell, self.lc.subunits, gates=True)
        self.sched = self.lc.sched
        self.layout = layout_for_cell(self.cell)
        self.position = position
        self.phases: list[Phase] = []
        self.phase: Phase | None = None
        self.sched.on_tick(self._record, "guard-demo.record", order=ORDER_GUARD + 1)
        self.lc.run_for(0.2)  # the cell is up before droid-home runs

    def close(self) -> None:
        self.lc.close()

    def arm(self, name: str):
        return self.lc.subunits[name].arm

    def model(self, name: str):
        return self.lc.subunits[name].parts.model

    def joints(self, name: str) -> np.ndarray:
        st = self.arm(name).read()
        return self.model(name).gearing.counts_to_joints(np.asarray(st["encoder_pos"], float))

    # -- the verdicts ------------------------------------------------------------------------------
    def begin(self, name: str) -> Phase:
        self.phase = Phase(name)
        self.phases.append(self.phase)
        self._trips0 = self.guard.core.trips
        return self.phase

    def _record(self, tick: int) -> None:
        v, ph = self.guard.last, self.phase
        if v is None or ph is None:
            return
        ph.ticks += 1
        ph.states[v.state] += 1
        if v.distance_mm < ph.least_mm:
            ph.least_mm, ph.least_pair, ph.closing_at_least = v.distance_mm, v.pair, v.closing_mm_s
        ph.max_sp_mm = max(ph.max_sp_mm, v.separation_mm)
        ph.max_closing_mm_s = max(ph.max_closing_mm_s, v.closing_mm_s)
        ph.min_override = min([ph.min_override, *v.override.values()])
        ph.trips = self.guard.core.trips - self._trips0
        if ph.trips and ph.trip is None:
            ph.trip = (v.deciding_mm, v.deciding_pair, v.closing_mm_s, v.separation_mm)

    # -- the demo's steps ----------------------------------------------------------------------------
    def home(self, name: str, timeout_s: float = 90.0) -> Phase:
        """droid-home ``name``: HOME, run until homed and idle, then NORMAL."""
        ph = self.begin(f"home {name}")
        ph.ok = self.arm(name).home(timeout_s)
        ph.detail = f"at {self.sched.t_s:.1f} s"
        return ph

    def _move(self, name: str, ph: Phase, cmd_id: int, seconds: float) -> Phase:
        arm = self.arm(name)
        done = arm.move_done(cmd_id, 3 * seconds + 30.0)
        st = arm.read()
        ph.ok = done and int(st["cmd_result"]) == 0
        ph.detail = f"{seconds:.1f} s move, cmd_result {int(st['cmd_result'])}, fault {int(st['fault'])}"
        self.sched.run_for(0.5)  # droid-seamtrack lets the servo settle
        return ph

    def move_to_start(self, name: str, T: np.ndarray, what: str) -> Phase:
        """A straight cartesian move to the wrist-centre pose ``T`` in droid-seamtrack's start-move time."""
        ph = self.begin(what)
        m = self.model(name)
        q_now = self.joints(name)
        q = m.ik(T, q_now)
        seconds = max(START_MOVE_MIN_S, START_MOVE_MARGIN * float(np.max(np.abs(q - q_now) / m.vmax_deg_s)))
        arm = self.arm(name)
        return self._move(name, ph, arm.command_cart(T, arm.ticks_for(seconds)), seconds)

    def move_joint(self, name: str, q_deg, seconds: float, what: str) -> Phase:
        """droid-move ``name`` joint ... ``seconds``: a joint move to ``q_deg`` [deg]."""
        ph = self.begin(what)
        arm = self.arm(name)
        counts = np.rint(self.model(name).gearing.joints_to_counts(np.asarray(q_deg, float))).astype(int)
        return self._move(name, ph, arm.command_joint(counts, arm.ticks_for(seconds)), seconds)

    def start_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """The welder's and the holder's wrist-centre poses at the start of the position."""
        return self.layout.start_poses(self.position)

    def track(self, speed_mm_s: float = 16.0, length_mm: float = 400.0, mode: str = "plus",
              max_s: float = 120.0) -> Phase:
        """droid-seamtrack ``speed --mode mode --length length`` from where the arms stand."""
        from droid.tasks.seam.params import SeamParams
        from droid.tasks.seam.stops import STOP_END
        from droid.tasks.seam.cycle import TrackingCycle
        from droid.tasks.seam.station import ArmStatus, SeamtrackStation
        from droid.tasks.seamtrack import pose_of, reading_of

        ph = self.begin(f"track {length_mm:g} mm at {speed_mm_s:g} mm/s ({mode})")
        lay, cell = self.layout, self.cell
        welder, holder = self.arm(lay.tool_robot), self.arm(lay.holder_robot)
        wrist = lay.wrist("standard")
        cyc = TrackingCycle(SeamParams(speed_mm_s=speed_mm_s, length_mm=length_mm, mode=mode), wrist.T_wcp_tool,
                            wrist.T_wcp_sensor, self.model(lay.tool_robot), heartbeat_hz=cell.heartbeat_hz)
        station = SeamtrackStation(cyc, cell.heartbeat_hz)
        lead = self.lc.subunits[lay.sensor].status
        state = {"stop": None, "travel": 0.0}

        def status(name, arm, rec):
            m = self.model(name)
            return ArmStatus(name, int(rec["tick"]), pose_of(rec), int(rec["fault"]), bool(int(rec["stale"])),
                             joints_deg=lambda: m.gearing.counts_to_joints(np.asarray(rec["encoder_pos"], float)))

        def tick(t: int) -> None:
            if state["stop"] is not None:
                return
            res = station.on_tick(t, status(lay.tool_robot, welder, welder.read()),
                                  status(lay.holder_robot, holder, holder.read()),
                                  lambda: (reading_of(lead.read(), cell.period_ns), int(lead.read()["tick"])))
            if station.out is not None:
                state["travel"] = station.out.travel_mm
            if res.stop is not None:
                state["stop"] = res.stop
                return
            if res.tool_cmd is not None:
                welder.command_cart(res.tool_cmd, station.cycle_ticks)
            if res.hold_cmd is not None:
                holder.command_cart(res.hold_cmd, station.cycle_ticks)

        self.sched.on_tick(tick, "guard-demo.seamtrack", order=ORDER_TASK)
        end = self.sched.t_s + max_s
        while state["stop"] is None and self.sched.t_s < end:
            self.sched.run_for(1.0)
        self.sched.remove("guard-demo.seamtrack")
        stop = state["stop"]
        ph.ok = stop is not None and stop.reason == STOP_END
        ph.detail = (f"stopped: {stop.reason} ({stop.detail}) at {state['travel']:.1f} mm" if stop is not None
                     else f"no stop in {max_s:g} s ({state['travel']:.1f} mm)")
        return ph
