"""Coordination in lockstep (issue 41 item 4; docs/guard.md §9 "Coordination on a held-out cell"):
one arm holds until the other's move ends, on a cell not among the shipped ones.

tests/guard/cells/overlap_pair.toml: two Reis-class arms facing each other, bases 1800 mm apart,
so their reaches overlap in the middle; the live guard on (``[guard] run = true``: droid-guard's
station and every planner's gate from the first tick, ``attach_lockstep(..., gates=True)``).
Both arms homed, then at their starts -- arm1 outstretched at joint 1 = -60 deg, arm2 tucked --
two moves whose paths cross the shared region:

* **the sweep**: arm1's joint 1 from -60 to +60 deg in 4 s (30 deg/s), outstretched: through the middle and out;
* **the reach**: arm2 from tucked to outstretched toward arm1 (joint 1 at 0) in 1.5 s: into the middle.

The reach is asked for 0.5 s into the sweep.  With a wait (droid-move ``--wait-clear``: the same
rule, droid.tasks.guarded.wait_clear_step, driven each tick on the lockstep records) it holds
until the sweep has ended, then goes: both moves complete, the guard never stops or slows, the
least separation stays above the limit.  The control: the same reach without a wait is refused
(the line of droid-move's refusal); and commanded anyway, at once, with no check, the guard
stops both arms (FAULT_COLLISION) above the stated limit C.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from droid.guard.station import ORDER_GUARD
from droid.sim.lockstep import ORDER_TASK
from droid.tasks.guarded import GO, HOLD, REFUSE, other_arm_of, wait_clear_step
from tests.guard.demo import DemoRun

CELL = Path(__file__).resolve().parent / "cells" / "overlap_pair.toml"
OUT_DEG = (-50.0, 30.0, 0.0, 20.0, 0.0)  # joints 2-6 of an outstretched arm [deg]
SWEEP_FROM = np.array([-60.0, *OUT_DEG])
SWEEP_TO = np.array([60.0, *OUT_DEG])
SWEEP_S = 4.0
TUCK = np.array([0.0, 20.0, -10.0, 0.0, 0.0, 0.0])
REACH_TO = np.array([0.0, *OUT_DEG])
REACH_S = 1.5
ASK_AFTER_S = 0.5  # the reach is asked for this long into the sweep
WAIT_S = 10.0  # --wait-clear
C_MM, CZ_MM = 25.0, 35.0  # reis_pair's [guard] ssm defaults: the stated limit C, and C + Z


class WaitClear:
    """arm2's move asked through the --wait-clear rule on every lockstep tick (a task's station)."""

    def __init__(self, r: DemoRun, wait_s: float) -> None:
        self.r, self.wait_s = r, wait_s
        self.scene = r.guard.core.scene
        p = r.guard.core.params
        self.limit_mm = p.clearance_mm + p.uncertainty_mm
        self.t0 = None
        self.holding = False
        self.held_ticks = 0
        self.line: str | None = None  # the first HOLD's reason, or the refusal
        self.action: str | None = None
        self.cmd_id: int | None = None
        self.go_tick: int | None = None

    def on_tick(self, tick: int) -> None:
        if self.action is not None:
            return
        self.t0 = tick if self.t0 is None else self.t0
        r = self.r
        sub = r.lc.subunits["arm1"]
        others = {"arm1": other_arm_of(sub.arm.read(), sub.command.read(), r.model("arm1").gearing,
                                       r.cell.heartbeat_hz)}
        action, line = wait_clear_step(self.scene, "arm2", r.joints("arm2"), REACH_TO, REACH_S, others,
                                       self.limit_mm, (tick - self.t0) / r.cell.heartbeat_hz, self.wait_s,
                                       self.holding)
        if action == HOLD:
            self.held_ticks += 1
            if line is not None and not self.holding:
                self.holding, self.line = True, line
            return
        self.action = action
        if action == REFUSE:
            self.line = line
            return
        arm = r.arm("arm2")
        counts = np.rint(r.model("arm2").gearing.joints_to_counts(REACH_TO)).astype(int)
        self.cmd_id, self.go_tick = arm.command_joint(counts, arm.ticks_for(REACH_S)), tick


def _start(r: DemoRun) -> None:
    """arm2 tucked first, then arm1 outstretched at the sweep's start (neither passes the other; arm1
    back at the sweep's pace: its servo does not follow an outstretched joint 1 much faster,
    docs/guard.md §6)."""
    for name, q, s, what in (("arm2", TUCK, 2.0, "arm2 tucked"), ("arm1", SWEEP_FROM, SWEEP_S, "arm1 at the sweep's start")):
        ph = r.move_joint(name, q, s, what)
        assert ph.ok and ph.trips == 0, ph.line()


def _sweep(r: DemoRun) -> int:
    arm = r.arm("arm1")
    counts = np.rint(r.model("arm1").gearing.joints_to_counts(SWEEP_TO)).astype(int)
    return arm.command_joint(counts, arm.ticks_for(SWEEP_S))


def _ended(r: DemoRun, name: str, cmd_id: int) -> tuple[bool, int]:
    """(the move ``cmd_id`` of ``name`` ended, its cmd_result), running the cell until it has."""
    done = r.arm(name).move_done(cmd_id, 30.0)
    return done, int(r.arm(name).read()["cmd_result"])


def test_one_arm_holds_until_the_others_move_ends_and_both_complete():
    r = DemoRun(str(CELL))
    try:
        for name in ("arm1", "arm2"):
            ph = r.home(name)
            assert ph.ok and ph.trips == 0, ph.line()
        _start(r)
        hz = r.cell.heartbeat_hz

        # the control, asked without a wait: refused at once (nothing written, arm2 never moves)
        ph = r.begin("the reach without a wait, 0.5 s into the sweep")
        sweep = _sweep(r)
        r.sched.run_for(ASK_AFTER_S)
        ask = WaitClear(r, 0.0)
        r.sched.on_tick(ask.on_tick, "wait-clear", order=ORDER_TASK)
        r.sched.run_for(2.0 / hz)
        r.sched.remove("wait-clear")
        assert ask.action == REFUSE and ask.line.startswith("would collide: arm2 ") and ask.cmd_id is None
        assert ask.line.endswith(f"< {CZ_MM:.0f} mm)"), ask.line
        assert _ended(r, "arm1", sweep) == (True, 0) and ph.trips == 0
        assert int(r.arm("arm2").read()["busy"]) == 0  # arm2 never moved
        print(f"without a wait: refused: {ask.line}")
        r.sched.run_for(0.5)
        _start(r)

        # with a wait: the reach holds until the sweep has ended, then goes; both complete
        ph = r.begin("the reach with --wait-clear, 0.5 s into the sweep")
        sweep = _sweep(r)
        r.sched.run_for(ASK_AFTER_S)
        ask = WaitClear(r, WAIT_S)
        sweep_end = {}
        r.sched.on_tick(ask.on_tick, "wait-clear", order=ORDER_TASK)
        r.sched.on_tick(lambda t: sweep_end.setdefault("tick", t) if int(r.arm("arm1").read()["busy"]) == 0 else None,
                        "sweep-end", order=ORDER_GUARD + 2)
        done1 = _ended(r, "arm1", sweep)
        deadline = r.sched.t_s + WAIT_S + 1.0
        while ask.action is None and r.sched.t_s < deadline:
            r.sched.run_for(1.0 / hz)
        r.sched.remove("wait-clear")
        r.sched.remove("sweep-end")
        assert ask.action == GO and ask.line is not None and ask.line.startswith("would collide: arm2 ")
        done2 = _ended(r, "arm2", ask.cmd_id)
        r.sched.run_for(0.5)
        ph.ok, ph.detail = done1 == done2 == (True, 0), f"sweep {done1}, reach {done2} (done, cmd_result)"
        print(ph.line())
        print(f"with a wait: held {ask.held_ticks} ticks ({ask.held_ticks / hz:.2f} s; first: {ask.line}), "
              f"went at tick {ask.go_tick}, the sweep ended at tick {sweep_end['tick']}")
        assert done1 == (True, 0) and done2 == (True, 0), ph.line()
        assert ask.go_tick >= sweep_end["tick"]  # it went once the sweep had ended, not before
        assert ask.held_ticks >= (SWEEP_S - ASK_AFTER_S) * hz - 3
        assert ph.trips == 0 and set(ph.states) == {"clear"} and ph.min_override == 1.0, ph.line()
        assert ph.least_mm > CZ_MM and ph.max_sp_mm < ph.least_mm, ph.line()
        wait_least = ph.least_mm

        # the control, commanded at once with no check: the guard stops both arms above C
        arm2 = r.arm("arm2")
        ph = r.move_joint("arm2", TUCK, 2.0, "arm2 tucked again")
        assert ph.ok and ph.trips == 0, ph.line()
        _start(r)
        ph = r.begin("the sweep and the reach at once, no check")
        sweep = _sweep(r)
        r.sched.run_for(ASK_AFTER_S)
        counts = np.rint(r.model("arm2").gearing.joints_to_counts(REACH_TO)).astype(int)
        reach = arm2.command_joint(counts, arm2.ticks_for(REACH_S))
        res1, res2 = _ended(r, "arm1", sweep), _ended(r, "arm2", reach)
        r.sched.run_for(1.0)
        ph.ok, ph.detail = True, f"sweep {res1}, reach {res2} (done, cmd_result: 1 failed)"
        print(ph.line())
        assert ph.trips >= 1 and "stopped" in ph.states, ph.line()
        assert 1 in (res1[1], res2[1])  # a move ended CMD_FAILED by the protective stop
        assert ph.least_mm > C_MM, ph.line()  # the stated limit kept by the stop
        assert ph.least_mm < wait_least  # the waiting run kept them farther apart
    finally:
        r.close()


def test_a_move_is_checked_to_the_end_of_the_other_arms_longer_move():
    """droid-move's check (droid.guard.refuse.check_move, also --wait-clear's) follows an other arm's
    move that outlasts this one to its end, this arm standing at its goal: the reach (1.5 s) asked
    0.25 s into an 8 s sweep ends clear of arm1, whose sweep then runs into it."""
    from droid.brain.cell.cellfile import load_cell
    from droid.guard.cell import guard_scene
    from droid.guard.refuse import check_move

    scene = guard_scene(load_cell(CELL))
    sweep_s, ask_s = 8.0, 0.25
    j1 = SWEEP_FROM[0] + (SWEEP_TO[0] - SWEEP_FROM[0]) * ask_s / sweep_s
    now = {"arm1": np.array([j1, *OUT_DEG])}
    line = check_move(scene, "arm2", TUCK, REACH_TO, REACH_S, now, {"arm1": (SWEEP_TO, sweep_s - ask_s)}, CZ_MM)
    assert line is not None and " after the move (+" in line and line.endswith(f"< {CZ_MM:.0f} mm)"), line
    # over the reach itself the two stay apart: only the sweep's rest brings arm1 into arm2's goal
    f = np.linspace(0.0, 1.0, 31)
    q1 = now["arm1"] + (REACH_S * f / (sweep_s - ask_s))[:, None] * (SWEEP_TO - now["arm1"])
    q2 = TUCK + f[:, None] * (REACH_TO - TUCK)
    assert float(scene.distances({"arm1": q1, "arm2": q2}).min()) > CZ_MM
    # the sweep done first (arm1 at its end): the reach is clear
    assert check_move(scene, "arm2", TUCK, REACH_TO, REACH_S, {"arm1": SWEEP_TO}, {}, CZ_MM) is None
