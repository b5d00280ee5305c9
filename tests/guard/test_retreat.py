"""A retreat counts as what it is: an arm moving away pays for the other's approach (issue 41;
ISO 10218-2:2025's speed *toward*; docs/guard.md §5).

Lockstep, GuardCore alone on the built-in cell (droid/cells/sim.toml): arm1 at rest ~47 mm from the
Fanuc (gmf1) where a head-on course would have met it -- found as
tests/guard/test_guard_live.py::test_a_head_on_course_is_slowed_or_stopped_above_the_limit finds
it, with check_move -- then commanded back to its start with a 4 s joint move (the planner's
way-points: linear interpolation), fed to GuardCore.step tick by tick at 60 Hz through the encoder
counts, the measured joints 2-4 ticks behind the commanded way-point.

With gmf1 at rest the signed rule and the old one (a retreat counted as 0) give the same closing
speed exactly; neither stops this retreat while the measured pose only moves away.  A measured
pose that steps back toward the Fanuc (the sample's lag growing by 2 ticks or more from one sample
to the next) is read by both as an approach at about the retreat's own speed (66-86 mm/s, S_p
52-56 mm at 47-51 mm): that reproduces the live cell's stop (closing 81 mm/s, S_p 55.3 mm at
51.9 mm), and this change does not address it.
"""
from __future__ import annotations

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.guard.refuse import check_move
from droid.guard.station import guard_core
from droid.kinematics import load_robot

from tests.guard.test_cell import SIM

HZ = 60.0
CELL = load_cell(SIM)
GEARING = {n: load_robot(CELL.subunits[n].robot).gearing for n in ("arm1", "gmf1")}
START = np.zeros(6)  # where homing leaves both arms (encoders at 0)
STOP_MM = 47.0  # the live cell's stop: 46.6 mm from the Fanuc (CI, 2026-12-03)


def _counts(name: str, q_deg) -> np.ndarray:
    """Joints [deg] as the Status gives them: through the encoder counts."""
    g = GEARING[name]
    return g.counts_to_joints(np.rint(g.joints_to_counts(np.asarray(q_deg, float))))


def _stop_pose():
    """arm1's pose ~STOP_MM from gmf1 on the first head-on course from the start that would meet it."""
    core = guard_core(CELL)
    model = load_robot(CELL.subunits["arm1"].robot)
    goal = None
    for j2 in range(-20, -91, -10):
        for j3 in range(0, 121, 20):
            g = START.copy()
            g[1], g[2] = j2, j3
            if not model.limit_violation(g) and check_move(core.scene, "arm1", START, g, 3.0, {"gmf1": START},
                                                           limit_mm=0.0):
                goal = g
                break
        if goal is not None:
            break
    assert goal is not None
    for s in np.linspace(0.0, 1.0, 2001):
        q = START + s * (goal - START)
        if core.scene.closest({"arm1": q, "gmf1": START}).distance_mm < STOP_MM:
            return q
    raise AssertionError("the head-on course never comes within 47 mm")


STOP = _stop_pose()


def _retreat(seconds=4.0, lag=(2, 4), repeat=0.0, gmf1_j2_deg_s=0.0, gmf1_from=0, seed=0, after=30):
    """arm1 back from STOP to START over ``seconds`` (1.5 s at rest before), gmf1's joint 2 at
    ``gmf1_j2_deg_s`` from tick ``gmf1_from``.  The measured joints ``lag`` ticks behind the way-point
    (a new lag each sample, never a step back: the arm does not reverse); arm1's Status sample repeats
    (its ``ticks`` the same for 1-3 guard ticks, then a jump) with probability ``repeat``, gmf1's with it
    (one host stalls both).  The verdicts of ticks 0.. and the least distance of each."""
    rng = np.random.default_rng(seed)
    core = guard_core(CELL)
    n = int(round(seconds * HZ))

    def way_point(t: int) -> np.ndarray:
        return _counts("arm1", STOP + min(1.0, max(0, t) / n) * (START - STOP))

    held, sample, lag_now, seen = 0, -90, lag[1], -10 ** 9
    out = []
    for tick in range(-90, n + after):
        if held:
            held -= 1
        else:
            sample = tick
            if rng.random() < repeat:
                held = int(rng.integers(1, 4))
            lag_now = min(max(int(rng.integers(lag[0], lag[1] + 1)), lag_now - 2), lag_now + 1)
        seen = max(seen, sample - lag_now)
        q_gmf1 = _counts("gmf1", START + np.array([0.0, 1.0, 0, 0, 0, 0]) * gmf1_j2_deg_s * max(0, sample - gmf1_from) / HZ)
        q = {"arm1": way_point(seen), "gmf1": q_gmf1}
        v = core.step(q, {"arm1": way_point(sample), "gmf1": q_gmf1}, None,
                      {"arm1": 1000 + sample, "gmf1": 1000 + sample})
        if tick >= 0:
            out.append(v)
    return core, out


def test_the_stop_pose_is_near_the_fanuc_and_at_rest_clear():
    core, vs = _retreat(seconds=4.0, after=0)
    assert 45.0 < vs[0].distance_mm < 50.0 and "gmf1." in vs[0].pair[0] + vs[0].pair[1]
    assert vs[0].distance_mm > core.params.separation_mm(0.0)  # at rest: clear of S_p's floor (35 mm)


@pytest.mark.parametrize("seed", range(6))
def test_a_retreat_beside_the_fanuc_at_rest_is_not_stopped(seed):
    """gmf1 at rest, arm1's 4 s retreat with the measured joints 2-4 ticks behind and its Status
    repeating: never stopped (with one side at rest the signed rule and the old one agree; this is
    the retreat of the live cell's log, a regression guard)."""
    _, vs = _retreat(seconds=4.0, repeat=0.15, seed=seed)
    assert not any(v.stop for v in vs), next(v for v in vs if v.stop)


@pytest.mark.parametrize("lag", [2, 3, 4])
def test_a_retreat_faster_than_the_other_arm_approaches_is_no_closing(lag):
    """gmf1 turns toward arm1 (joint 2 at 3.75 deg/s, ~59 mm/s at its closest point) while arm1
    retreats faster: the separation grows, so the pair is not closing.  Counting arm1's retreat as
    0 read gmf1's approach alone (59 mm/s, S_p 49.7 mm) and stopped both arms at 47-49 mm; as ISO
    states it (each side's speed toward the other, signed) the closing speed is 0."""
    core, vs = _retreat(seconds=4.0, lag=(lag, lag), gmf1_j2_deg_s=-3.75, gmf1_from=4)
    d = np.array([v.distance_mm for v in vs])
    assert d[240] > d[0] + 50.0  # the separation grew
    near = np.flatnonzero(d[:240] < 100.0)  # where S_p can matter (35 mm + 0.25 s x v)
    near = near[near >= lag + 2]  # arm1's measured joints under way
    assert len(near) > 30 and np.all(np.diff(d[near[0]:near[-1] + 1]) > 0.0)  # ... every tick there
    assert not any(v.stop for v in vs[:240]), next(v for v in vs if v.stop)
    assert max(vs[i].closing_mm_s for i in near) == 0.0


def test_a_retreat_slower_than_the_other_arm_approaches_still_closes():
    """The same but arm1 retreats over 12 s and gmf1 turns at 4 deg/s (~62 mm/s): the separation
    falls, the pair's closing speed is gmf1's approach less arm1's retreat (and never less than the
    fall of its distance); the stop trips above the stated limit C."""
    core, vs = _retreat(seconds=12.0, lag=(3, 3), gmf1_j2_deg_s=-4.0, gmf1_from=4)
    stopped = next((i for i, v in enumerate(vs) if v.stop), None)
    assert stopped is not None and vs[stopped].distance_mm > core.params.clearance_mm
    assert 10.0 < vs[stopped].closing_mm_s < 62.0  # less than gmf1's approach alone: arm1's retreat counts
    d = np.array([v.distance_mm for v in vs[:stopped + 1]])
    assert d[stopped] < d[0]
