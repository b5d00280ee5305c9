"""The closing speed per pair along its separation direction, re-zeros and arms not homed (issue 41;
docs/guard.md §5).

GuardCore on cell scenes, stepped with joint vectors: a sideways swing is no closing speed (ISO's
speed *toward*), an approach is (never less than the fall of the pair's own distance), the verdict
is the pair with the least margin d - S_p, an overlapping pair (no direction) falls back to both
bodies' fastest points; a measured step over the joint speed limit is a re-zero, not a speed; an
arm not homed is not judged while the home poses are clear, and holds the stop otherwise; a speed
is measured over the ticks between two refreshes of an arm's Status.
"""
from __future__ import annotations

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.experiments.guard_trial import trial_cell
from droid.guard.core import JUMP_MARGIN
from droid.guard.station import guard_core

from tests.guard.test_cell import SIM

HZ = 60.0


def _old_rule_mm_s(core, q0: dict, q1: dict) -> float:
    """The rule this replaces: the sum over the arms of each arm's fastest body point (joint origins
    and flange) between two ticks, as if both came straight at each other."""
    v = 0.0
    for name, chain in core.scene.arms.items():
        a, _ = chain.points(np.radians(np.asarray(q0[name], float))[None])
        b, _ = chain.points(np.radians(np.asarray(q1[name], float))[None])
        v += float(np.max(np.linalg.norm(b[0] - a[0], axis=1))) * HZ
    return v


def _check_the_verdict_is_the_least_margin(core, v) -> None:
    f = core.pairs_now
    idx = np.flatnonzero(f.judged)
    margin = f.distance_mm[idx] - f.separation_mm[idx]
    k = idx[int(np.argmin(margin))]
    assert v.deciding_pair == core.pair_keys[k] and v.deciding_mm == f.distance_mm[k]
    assert v.closing_mm_s == f.closing_mm_s[k] and v.separation_mm == f.separation_mm[k]
    least = idx[int(np.argmin(f.distance_mm[idx]))]
    assert v.pair == core.pair_keys[least] and v.distance_mm == f.distance_mm[least]
    assert np.allclose(f.separation_mm, core.params.separation_mm(0.0) + f.closing_mm_s * 0.25)
    assert (f.closing_mm_s >= 0.0).all()
    if not v.stop:
        assert (f.distance_mm[idx] > f.separation_mm[idx]).all()


def test_a_sideways_swing_is_no_closing_speed():
    """Two Reis-class arms reach at each other (forearms 257 mm apart); arm1 swings joint 1 at its
    full 100 deg/s: its forearm's tip moves over 1 m/s across the separation, not along it.  The old
    rule's S_p (its sum of fastest points) is over 285 mm, past the distance: it stopped the
    arms; the closing speed along the pair's direction is ~0 and the guard lets them be."""
    core = guard_core(trial_cell())
    q = {n: np.array([0.0, -20.0, 0.0, 0.0, 0.0, 0.0]) for n in ("arm1", "arm2")}
    v = core.step(q)
    assert 250.0 < v.distance_mm < 265.0 and v.pair == ("arm1.link_4", "arm2.link_4")
    step = np.array([100.0 / HZ, 0, 0, 0, 0, 0])
    for _ in range(6):
        q1 = {"arm1": q["arm1"] + step, "arm2": q["arm2"]}
        old = _old_rule_mm_s(core, q, q1)
        v = core.step(q1, {"arm1": q1["arm1"] + step, "arm2": q1["arm2"]})  # planner-like: the next way-point ahead
        q = q1
        assert old > 1000.0 and core.params.separation_mm(old) > v.distance_mm  # the old rule would stop here
        assert v.closing_mm_s < 10.0, v
        assert v.state == "clear" and not v.stop
        _check_the_verdict_is_the_least_margin(core, v)


def test_an_approach_is_its_speed_toward_and_stops_before_the_limit():
    """Both arms lean toward each other (joint 2 forward at 60 deg/s each, the forearms level): each
    side's approach along the pair's direction adds up, never less than the fall of the pair's
    distance -- the stop trips, above the stated limit C."""
    core = guard_core(trial_cell())
    q = {n: np.array([0.0, 10.0, 0.0, 0.0, 0.0, 0.0]) for n in ("arm1", "arm2")}
    step = np.array([0.0, -60.0 / HZ, 0.0, 0.0, 0.0, 0.0])
    v = core.step(q)
    last = v.distance_mm
    stopped = None
    for _ in range(300):
        q = {n: q[n] + step for n in q}
        v = core.step(q, {n: q[n] + step for n in q})
        f = core.pairs_now
        k = core.pair_keys.index(v.pair)
        fall = (last - f.distance_mm[k]) * HZ
        assert f.closing_mm_s[k] >= fall - 1e-6  # never less than the pair's own fall
        last = v.distance_mm
        _check_the_verdict_is_the_least_margin(core, v)
        if v.stop:
            stopped = v
            break
    assert stopped is not None and stopped.distance_mm > core.params.clearance_mm
    assert stopped.closing_mm_s > 100.0  # both sides' approach: the arms do close


def test_an_overlapping_pair_takes_both_bodies_fastest_points():
    """No direction between bodies that overlap: the pair's closing speed is both bodies' fastest
    feature points (a capsule's ends) as if straight at each other -- the conservative fallback."""
    text = SIM.read_text().replace("base = [2000.0, 0.0, 0.0, 180.0, 0.0, 0.0]", "base = [900.0, 0.0, 0.0, 180.0, 0.0, 0.0]")
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "near.toml"
        path.write_text(text)
        core = guard_core(load_cell(path))
    q0 = {"arm1": np.zeros(6), "gmf1": np.zeros(6)}
    q1 = {"arm1": np.array([1.0, 0, 0, 0, 0, 0]), "gmf1": np.zeros(6)}
    core.step(q0)
    v = core.step(q1)
    assert v.stop and v.distance_mm < 0.0
    k = core.pair_keys.index(("arm1.tool", "gmf1.link_2"))
    assert core.pairs_now.distance_mm[k] < 0.0
    sc = core.scene
    p0a, p1a, _, _ = sc._poses({n: q0[n][None] for n in q0})
    p0b, p1b, _, _ = sc._poses({n: q1[n][None] for n in q1})
    c = next(i for i, b in enumerate(sc.caps) if b.key == "arm1.tool")
    want = max(np.linalg.norm(p0b[0, c] - p0a[0, c]), np.linalg.norm(p1b[0, c] - p1a[0, c])) * HZ
    assert core.pairs_now.closing_mm_s[k] == pytest.approx(want, rel=1e-9)  # gmf1 link 2 stands: 0


def _homed_sim():
    core = guard_core(load_cell(SIM))
    home = {n: c.home_deg.copy() for n, c in core.scene.arms.items()}
    return core, home


def test_a_step_over_the_joint_speed_limit_is_a_re_zero_not_a_speed():
    core, q = _homed_sim()
    core.step(q)
    jumped = dict(q, gmf1=q["gmf1"] + np.array([0, 0, 0, 0, 0, 170.0]))  # the counts zeroed: 170 deg in a tick
    v = core.step(jumped)
    assert core.jumps == 1 and len(v.notes) == 1 and v.notes[0].startswith("gmf1 joint 6 stepped 170.0 deg in 1 tick")
    assert "a re-zero, not motion" in v.notes[0]
    assert v.closing_mm_s == 0.0 and not v.stop and v.state == "clear"  # no speed measured across it
    v = core.step(jumped)
    assert v.notes == () and not v.stop  # said once
    # the arm's motion after it is measured again: joint 1 at 30 deg/s (under the limit)
    limit = JUMP_MARGIN * core.scene.arms["gmf1"].vmax_deg_s[0] / HZ
    moving = dict(jumped)
    speeds = []
    for _ in range(5):
        moving = dict(moving, gmf1=moving["gmf1"] + np.array([30.0 / HZ, 0, 0, 0, 0, 0]))
        v = core.step(moving)
        speeds.append(float(np.max(core.pairs_now.closing_mm_s)))
    assert 30.0 / HZ < limit and core.jumps == 1 and max(speeds) > 0.0


def test_an_arm_not_homed_is_not_judged_while_the_home_poses_are_clear():
    core, q = _homed_sim()
    assert core.homes_clear
    lost = dict(q, gmf1=np.array([0.0, -90.0, 60.0, 0.0, 0.0, 0.0]))  # counts from an unknown power-up pose
    assert core.scene.closest(lost).distance_mm < 0.0  # read as a pose, it is in arm1
    v = core.step(lost, homed={"arm1": True, "gmf1": False})
    assert v.unjudged == ("gmf1",) and not v.stop and v.state == "clear"
    assert v.notes == ("gmf1 not homed: its position is unknown, its pairs are not judged (the home poses are "
                       "clear of each other)",)
    assert all(not core.pairs_now.judged[k] for k, (a, b) in enumerate(core.pair_keys) if "gmf1." in a + b)
    v = core.step(lost, homed={"arm1": True, "gmf1": False})
    assert v.notes == ()  # said once
    v = core.step(q, homed={"arm1": True, "gmf1": True})  # homed: at home, the counts re-zeroed
    assert v.unjudged == () and not v.stop and v.closing_mm_s == 0.0  # a new course: no speed across the jump
    assert v.notes == ("gmf1 homed: its pairs are judged again (a new course)",)


def test_an_arm_not_homed_holds_the_stop_where_the_home_poses_are_not_clear(tmp_path):
    text = SIM.read_text().replace("base = [2000.0, 0.0, 0.0, 180.0, 0.0, 0.0]", "base = [700.0, 0.0, 0.0, 180.0, 0.0, 0.0]")
    (tmp_path / "near.toml").write_text(text)
    core = guard_core(load_cell(tmp_path / "near.toml"))
    assert not core.homes_clear
    far = {"arm1": np.zeros(6), "gmf1": np.array([90.0, 0, 0, 0, 0, 0])}
    v = core.step(far, homed={"arm1": True, "gmf1": False})
    assert v.stop and v.state == "stopped" and "the protective stop is held on" in v.notes[0]


def test_a_speed_is_measured_over_the_ticks_between_refreshes():
    """An arm's Status refreshed every other tick (a stalled host, a slow link): the motion of two
    ticks comes in one.  Over the Status's own ticks it is the same speed as refreshed every tick;
    taken over the guard's tick it would read twice as fast."""
    step = np.array([0.0, -40.0 / HZ, 0.0, 0.0, 0.0, 0.0])

    def run(every: int, with_ticks: bool) -> float:
        core = guard_core(trial_cell())
        q = {n: np.array([0.0, 10.0, -30.0, 0.0, 0.0, 0.0]) for n in ("arm1", "arm2")}
        tick = {"arm1": 100, "arm2": 100}
        out = []
        for t in range(1, 13):
            if t % every == 0:
                q = dict(q, arm1=q["arm1"] + every * step)
                tick["arm1"] = 100 + t
            tick["arm2"] = 100 + t
            v = core.step(q, ticks=dict(tick) if with_ticks else None)
            out.append(float(np.max(core.pairs_now.closing_mm_s)))
        return max(out[4:])

    each = run(1, True)
    assert each > 50.0
    assert run(2, True) == pytest.approx(each, rel=0.05)
    assert run(2, False) == pytest.approx(2 * each, rel=0.05)


def _course(rng, n_ticks: int) -> list[dict]:
    """Both arms of the sim cell about home: spells at rest (the same joints tick after tick),
    spells of motion, one arm moving while the other stands, an approach that trips the stop."""
    core = guard_core(load_cell(SIM))
    home = {n: np.asarray(c.home_deg, float) for n, c in core.scene.arms.items()}
    q = {n: h.copy() for n, h in home.items()}
    out = []
    for t in range(n_ticks):
        spell = (t // 15) % 4  # 0: at rest, 1: arm1 moves, 2: both move, 3: at rest
        for i, n in enumerate(q):
            if spell == 2 or (spell == 1 and i == 0):
                q[n] = q[n] + rng.normal(0.0, 0.4, 6)
        out.append({n: v.copy() for n, v in q.items()})
    return out


def test_a_pass_at_rest_takes_the_tick_befores_figures_exactly():
    """At rest (every arm's rows as the tick before) the guard takes its last pass again instead
    of computing it: every verdict and every pair's figures are bit-identical to a guard that
    computes each pass, over spells of rest, motion and Status ticks that do not advance."""
    rng = np.random.default_rng(7)
    course = _course(rng, 240)
    a, b = guard_core(load_cell(SIM)), guard_core(load_cell(SIM))
    for t, q in enumerate(course):
        ticks = {n: 1 + t - (t % 3 == 1 and n == "gmf1") for n in q}  # gmf1's Status late every 3rd tick
        b._still = None  # b computes every pass
        va, vb = a.step(q, ticks=ticks), b.step(q, ticks=ticks)
        assert va == vb, t
        for f in ("distance_mm", "closing_mm_s", "separation_mm", "judged"):
            assert np.array_equal(getattr(a.pairs_now, f), getattr(b.pairs_now, f)), (t, f)
    assert a.still_passes > 60 and b.still_passes == 0


def test_a_stall_that_stretches_the_ticks_is_measured_by_the_refresh_times():
    """A host stall held every program for three periods: the arm's next Status is one tick newer
    but refreshed three periods later, carrying three periods' motion.  Over the refresh times it is
    the speed of a Status refreshed every period; over the ticks alone it reads three times as fast
    (session 32's false protective stop).  Two replies written back to back (a stalled remote) are
    still a tick apart: the speed is never read over less than the ticks."""
    step = np.array([0.0, -40.0 / HZ, 0.0, 0.0, 0.0, 0.0])
    period_ns = 1e9 / HZ

    def run(stall_at: int | None, with_stamps: bool, back_to_back: bool = False) -> list[float]:
        core = guard_core(trial_cell())
        q = {n: np.array([0.0, 10.0, -30.0, 0.0, 0.0, 0.0]) for n in ("arm1", "arm2")}
        tick, t_ns, out = 100, 5_000_000_000.0, []
        for t in range(1, 14):
            periods = 3 if t == stall_at else 1
            q = dict(q, arm1=q["arm1"] + periods * step)
            tick += 1
            t_ns += (0.0 if back_to_back and t == stall_at else periods * period_ns)
            stamps = {n: int(t_ns) for n in q} if with_stamps else None
            core.step(q, ticks={n: tick for n in q}, stamps_ns=stamps)
            out.append(float(np.max(core.pairs_now.closing_mm_s)))
        return out

    steady = max(run(None, True)[4:])
    assert steady > 50.0
    assert run(8, True)[7] == pytest.approx(steady, rel=0.05)
    assert run(8, False)[7] == pytest.approx(3 * steady, rel=0.05)
    assert run(None, True) == run(None, False)  # refreshed every period: the stamps change nothing
    # a reply written 0 ns after the last (a stalled remote) still covers its tick, not 0 ticks
    quick = run(8, True, back_to_back=True)
    assert np.isfinite(quick[7]) and quick[7] >= 3 * steady * 0.95
