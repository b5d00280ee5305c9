"""The guard's stopping time and distance against the Reis servo's braking, in lockstep (issue 41
item 2; docs/guard.md §5 "Stopping time and distance, measured"): tests/guard/braking.py stops
arm1's outstretched joint-1 sweep halfway with FAULT_COLLISION, as droid-guard's station does,
and reads the servo's own halt record (droid.subunits.reis.brake_log, droid-servo's ``halt``).

What S_p assumes must hold for what the servo does:

* the stopping time, fault -> standstill, is within ``stop_time_s`` (T_s);
* the distance the arm's fastest point travels after the fault, D_stop, is within what S_p gives
  a side after its verdict, v (T_r + T_s / 2), less the guard's own lag before the fault is
  written -- the Status a tick old and the guard's tick (2 heartbeat ticks at v);
* D_stop is proportional to v (the planner's ramp is a fixed number of ticks): one figure per
  arm, D_stop / v, is the whole of it.
"""
from __future__ import annotations

import pytest

from tests.guard.braking import BrakeTap, measure
from tests.guard.demo import DemoRun
from tests.guard.test_wait_clear import CELL

SHARES = (0.2, 0.5)  # of joint 1's vmax_deg_s (the servo follows an outstretched joint 1 up to ~0.5)


def test_the_servos_braking_is_within_the_guards_stopping_terms():
    r = DemoRun(str(CELL))
    try:
        assert r.home("arm1").ok
        p = r.guard.core.params
        lag_s = 2.0 / r.cell.heartbeat_hz
        tap = BrakeTap(r.sched, r.lc.subunits["arm1"].parts, "arm1")
        got = [measure(r, tap, s) for s in SHARES]
        for b in got:
            print(b.line())
        for b in got:
            assert 0.2 < b.stop_s <= p.stop_time_s, b.line()
            assert b.stop_mm <= b.v_mm_s * (p.reaction_s + 0.5 * p.stop_time_s - lag_s), b.line()
        assert got[1].v_mm_s > 2.0 * got[0].v_mm_s
        assert got[1].t_eff_s == pytest.approx(got[0].t_eff_s, rel=0.05)  # D_stop proportional to v
    finally:
        r.close()
