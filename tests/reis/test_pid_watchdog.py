"""PID anti-windup (thesis §4.1.5.1) and the watchdog core (§2.3, §4.1.4)."""
from __future__ import annotations

import numpy as np
import pytest

from droid.subunits.reis.pid import Pid
from droid.subunits.reis.watchdog import WatchdogCore, WatchdogParams, liveness_steps


def make_pid(**kw):
    args = dict(kp=[2.0] * 6, ki=[0.5] * 6, kd=[10.0] * 6, integral_limit=[300.0] * 6, out_min=-2048, out_max=2047)
    args.update(kw)
    return Pid(**args)


def test_pid_terms():
    pid = make_pid()
    out = pid.step(np.array([10, -10, 0, 1, 0, 0]))
    assert np.allclose(out, [2 * 10 + 5, -25, 0, 2.5, 0, 0])  # no derivative on the first step
    out = pid.step(np.array([12, -10, 0, 1, 0, 0]))
    assert np.allclose(out[0], 2 * 12 + (5 + 6) + 10 * 2)


def test_saturated_output_does_not_wind_up_the_integral():
    pid = make_pid(integral_limit=[5000.0] * 6)
    for _ in range(1000):
        out = pid.step(np.full(6, 2000.0))  # kp*e alone saturates
    assert np.all(np.asarray(out) == 2047)
    assert np.all(pid.integral == 0)  # nothing accumulated while saturated
    out = pid.step(np.full(6, -10.0))
    assert np.all(np.asarray(out) < 0)  # recovers at once when the error reverses


def test_integral_is_bounded_by_its_limit():
    pid = make_pid(kp=[0.0] * 6, kd=[0.0] * 6)
    for _ in range(10_000):
        out = pid.step(np.full(6, 3.0))
    assert np.allclose(pid.integral, 300.0)
    assert np.allclose(out, 300.0)


def test_reset_clears_integral_and_derivative_memory():
    pid = make_pid()
    pid.step(np.full(6, 50.0))
    pid.reset()
    assert np.all(pid.integral == 0)
    assert np.allclose(pid.step(np.full(6, 50.0)), 2 * 50 + 25)


def test_watchdog_kicks_changing_values_while_the_servo_ticks():
    wd = WatchdogCore()
    seen = [wd.step(servo_heartbeat=10 * i) for i in range(100)]
    assert all(k is not None for k in seen)
    for a, b in zip(seen, seen[1:]):
        assert a[0] != b[0] and a[1] != b[1]
    assert all(0 <= v <= 0xFFFF for k in seen for v in k)


def test_watchdog_stops_for_good_when_the_servo_heartbeat_stalls():
    wd = WatchdogCore(WatchdogParams(servo_liveness_steps=3))
    assert wd.step(1) is not None
    assert wd.step(1) is not None  # 1 stale step
    assert wd.step(1) is not None  # 2
    assert wd.step(1) is None  # 3 -> dead
    assert wd.servo_dead
    assert wd.step(2) is None  # latched: a revived heartbeat does not restart kicking
    wd.rearm()
    assert wd.step(3) is not None


def test_watchdog_stops_on_servo_fault_and_on_request():
    wd = WatchdogCore()
    assert wd.step(1) is not None
    assert wd.step(2, servo_fault=True) is None
    wd2 = WatchdogCore()
    wd2.step()
    wd2.declare_dead()
    assert wd2.step() is None


def test_watchdog_without_supervision_keeps_kicking():
    wd = WatchdogCore()
    assert all(wd.step() is not None for _ in range(70_000))  # wraps the 16-bit counter
    assert wd.kicks == 70_000


def test_watchdog_params_are_checked():
    with pytest.raises(ValueError):
        WatchdogParams(servo_liveness_steps=0)


@pytest.mark.parametrize("stale_ticks, heartbeat_hz, steps", [(3, 60.0, 3), (12, 60.0, 10), (1, 60.0, 1), (6, 30.0, 10)])
def test_the_watchdogs_liveness_is_the_cells_silence_rule_in_its_own_steps(stale_ticks, heartbeat_hz, steps):
    """droid-watchdog declares the servo dead after the cell's stale_ticks, in time [s],
    rounded up to whole 20 ms steps: the default cell's 3 ticks keep the 60 ms rule."""
    assert liveness_steps(stale_ticks, heartbeat_hz) == steps
    core = WatchdogCore(WatchdogParams(servo_liveness_steps=steps))
    core.step(7)
    for _ in range(steps - 1):
        assert core.step(7) is not None
    assert core.step(7) is None and core.servo_dead


@pytest.mark.parametrize("args", [(0, 60.0), (3, 0.0), (3, float("nan"))])
def test_liveness_steps_refuses_a_meaningless_rule(args):
    with pytest.raises(ValueError):
        liveness_steps(*args)
