"""The collision guard's protective stop on head-on and crossing courses in lockstep (issue 41).

The cell is cells/reis_pair.toml (two Reis-class arms with their real planners, servos and
plant twins) with the second arm's base moved to :data:`GAP_MM` from the first, so their
reaches overlap, and droid-guard's station (:mod:`droid.guard.station`) on the scheduler's
tick.  Both arms are homed once; then each trial, from a seed:

1. draws a course -- ``head-on`` (both arms stretch toward each other from a tucked pose) or
   ``crossing`` (both arms outstretched, joint 1 sweeping across the other's path) -- whose
   unguarded joint paths, at full speed together, would bring the bodies closer than the
   stated limit (the ``[guard] ssm`` clearance C);
2. moves both arms to the course's start with the guard off, releases it, turns it on;
3. commands both moves at once at full speed (the leading joint at its ``vmax_deg_s``);
4. runs until both moves have ended (done, or cancelled by FAULT_COLLISION) and the arms have
   come to rest, recording every tick the *true* joint angles of both plants (the world's
   truth, not the Status);

and the verdict is the least true distance over the trial [mm] (the guard's bodies, at the
plants' angles) against C.  ``bench/bench_guard_trials.py`` runs 200; tests/guard a seeded few.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from droid.brain.cell.cellfile import BUNDLED_CELLS, load_cell
from droid.guard.station import attach_lockstep
from droid.sim.lockstep_cell import build_lockstep_cell

PAIR = BUNDLED_CELLS / "reis_pair.toml"
GAP_MM = 1800.0  # arm2's base from arm1's along x [mm] (the cell file's is 2500: reaches that barely meet)
REPOSITION_S = 2.0  # the guard-off move to a course's start [s]
SETTLE_S = 0.6  # run on after both moves end, until the arms are at rest [s]
COURSES = ("head-on", "crossing")
#: the courses' speed as a fraction of the robot file's vmax_deg_s (the leading joint's): the
#: planner starts a move at its speed at once (no acceleration ramp), and from rest at full speed
#: the Reis's servo overruns its following-error limit on some courses (a servo fault: joint 1 of
#: an outstretched arm at 0.6 of full speed, joints 2-3 of some head-on courses at full speed),
#: so each kind runs at the fastest start the servo followed on every course drawn
SPEED = {"head-on": 0.8, "crossing": 0.45}


@dataclass
class Course:
    kind: str
    start: dict  # arm -> (6,) deg
    goal: dict  # arm -> (6,) deg


@dataclass
class TrialResult:
    seed: int
    kind: str
    min_true_mm: float  # least distance over the trial, at the plants' true angles
    unguarded_min_mm: float  # least distance along the unguarded paths
    stopped: bool  # the protective stop tripped
    limit_mm: float  # the stated limit C
    servo_fault: bool = False  # a servo faulted during the trial (the trial says nothing then)

    @property
    def kept(self) -> bool:
        return self.min_true_mm >= self.limit_mm


def trial_cell():
    """reis_pair.toml with arm2 at GAP_MM and an empty ``[guard]`` table: the two arms' links only
    (not the cell file's floor), default SSM terms."""
    cell = load_cell(PAIR)
    cell.subunits["arm2"].base = [GAP_MM, *cell.subunits["arm2"].base[1:]]
    cell.raw["guard"] = {}
    return cell


def _course(kind: str, rng: np.random.Generator) -> Course:
    start, goal = {}, {}
    for name in ("arm1", "arm2"):
        if kind == "head-on":
            j1 = rng.uniform(-15.0, 15.0)
            s = [j1, rng.uniform(20.0, 40.0), rng.uniform(-30.0, 0.0), rng.uniform(-30, 30), rng.uniform(-30, 30), 0.0]
            g = [j1 + rng.uniform(-10.0, 10.0), rng.uniform(-70.0, -50.0), rng.uniform(20.0, 50.0),
                 rng.uniform(-30, 30), rng.uniform(-30, 30), 0.0]
        else:
            sign = 1.0 if name == "arm1" else -1.0
            q2, q3 = rng.uniform(-55.0, -35.0), rng.uniform(15.0, 40.0)
            s = [-sign * rng.uniform(30.0, 60.0), q2, q3, 0.0, rng.uniform(-30, 30), 0.0]
            g = [sign * rng.uniform(30.0, 60.0), q2 + rng.uniform(-5, 5), q3 + rng.uniform(-5, 5), 0.0,
                 rng.uniform(-30, 30), 0.0]
        start[name], goal[name] = np.array(s), np.array(g)
    return Course(kind, start, goal)


def full_speed_s(model, q0, q1, fraction: float = 1.0) -> float:
    """The move's time [s] with its leading joint at ``fraction`` of the robot file's vmax_deg_s."""
    return float(np.max(np.abs(np.asarray(q1) - np.asarray(q0)) / (fraction * np.asarray(model.vmax_deg_s, float))))


def unguarded_min_mm(scene, models: dict, course: Course, hz: float) -> float:
    """The least distance [mm] along both arms' straight joint paths at full speed together."""
    secs = {n: full_speed_s(models[n], course.start[n], course.goal[n], SPEED[course.kind]) for n in course.start}
    T = max(secs.values())
    t = np.linspace(0.0, T, max(2, int(T * hz * 2)))
    q = {n: course.start[n] + np.clip(t / max(secs[n], 1e-9), 0.0, 1.0)[:, None] * (course.goal[n] - course.start[n])
         for n in course.start}
    return float(scene.distances(q).min())


def draw_course(kind: str, seed: int, scene, models: dict, limit_mm: float, hz: float) -> tuple[Course, float]:
    """A seeded course of ``kind`` that would, unguarded, come closer than ``limit_mm`` (and starts apart)."""
    rng = np.random.default_rng(seed)
    for _ in range(500):
        c = _course(kind, rng)
        if float(scene.distances({n: c.start[n][None] for n in c.start}).min()) < 400.0:
            continue
        u = unguarded_min_mm(scene, models, c, hz)
        if u < limit_mm:
            return c, u
    raise RuntimeError(f"no {kind} course for seed {seed} in 500 draws")


class GuardTrials:
    """One homed lockstep cell with the guard, running trials one after another."""

    def __init__(self) -> None:
        self.cell = trial_cell()
        self.lc = build_lockstep_cell(self.cell)
        self.arms = {n: self.lc.subunits[n].parts for n in ("arm1", "arm2")}
        self.guard = attach_lockstep(self.lc.sched, self.cell, self.lc.subunits)
        self.guard.enabled = False
        self.scene = self.guard.core.scene
        self.models = {n: a.model for n, a in self.arms.items()}
        self.hz = self.cell.heartbeat_hz
        self.lc.run_for(0.1)
        ids = {n: a.command_home() for n, a in self.arms.items()}
        ok = self.arms["arm1"].run_until(lambda: all(self._idle(n, i) and int(self.arms[n].status["homed"])
                                                    for n, i in ids.items()), 90.0, 0.5)
        if not ok:
            raise RuntimeError("the trial cell's arms did not home")
        for a in self.arms.values():
            a.set_normal()
        self._truth: list[dict] = []
        self.lc.sched.on_tick(self._record, "guard-trial.truth", order=99)
        self.recording = False

    def close(self) -> None:
        self.lc.close()

    def _idle(self, name: str, cmd_id: int) -> bool:
        st = self.arms[name].status
        return int(st["cmd_id"]) == cmd_id and int(st["busy"]) == 0

    def _record(self, tick: int) -> None:
        if self.recording:
            self._truth.append({n: a.plant.joint_deg.copy() for n, a in self.arms.items()})

    def _move_all(self, goal: dict, seconds: dict) -> dict:
        ids = {}
        for n, a in self.arms.items():
            counts = a.model.gearing.joints_to_counts(goal[n])
            ids[n] = a.command_joint(counts, max(1, int(math.ceil(seconds[n] * self.hz))))
        return ids

    def run(self, kind: str, seed: int) -> TrialResult:
        limit = self.guard.core.params.clearance_mm
        course, u = draw_course(kind, seed, self.scene, self.models, limit, self.hz)
        self.guard.enabled = False
        self.guard.release()
        ids = self._move_all(course.start, {n: REPOSITION_S for n in self.arms})
        self.arms["arm1"].run_until(lambda: all(self._idle(n, i) for n, i in ids.items()), REPOSITION_S + 3.0)
        self.lc.run_for(0.3)  # at rest at the start
        core = self.guard.core
        core.reset()
        trips0 = core.trips
        self.guard.enabled = True
        self._truth, self.recording = [], True
        secs = {n: full_speed_s(self.models[n], course.start[n], course.goal[n], SPEED[kind]) for n in self.arms}
        ids = self._move_all(course.goal, secs)
        self.arms["arm1"].run_until(lambda: all(self._idle(n, i) for n, i in ids.items()), max(secs.values()) + 3.0)
        self.lc.run_for(SETTLE_S)
        self.recording = False
        q = {n: np.array([row[n] for row in self._truth]) for n in self.arms}
        d = float(self.scene.distances(q).min())
        faulted = any(int(a.servo.fault) for a in self.arms.values())
        return TrialResult(seed, kind, d, u, core.trips > trips0, limit, faulted)
