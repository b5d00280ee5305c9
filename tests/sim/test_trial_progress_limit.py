"""A lockstep trial's time limit is a limit on progress (issue 13 item 5; trial.ProgressLimit):
``timeout`` when the tool's seam coordinate s stalls over a window, or at a generous hard cap --
not at 3 x length / commanded speed + 30 s, which ended the full arm's slow-but-tracking
thesis-mode trials (the tool follows at 12-38 % of the commanded speed there)."""
import math

import pytest

from droid.experiments.trial import ProgressLimit, TrialConfig, run_trial


def old_limit_s(length_mm, speed_mm_s):
    return 3.0 * length_mm / speed_mm_s + 30.0  # the limit before (TIME_LIMIT_FACTOR = 3)


def test_a_slow_but_progressing_trial_is_not_ended_by_the_old_limit():
    """700 mm at 16 mm/s commanded, the tool following at 12 % (1.92 mm/s, the slowest measured on
    the full arm: the 16 mm/s ramps) in a stick-slip staircase: 1 s stuck, 1 s slipping 3.84 mm,
    checked once a simulated second as the trial does.  It needs 365 s, the old limit was 161 s."""
    length, v = 700.0, 16.0
    w = ProgressLimit().watch(length, v)
    t, s = 0.0, 0.0
    while s < length:
        t += 1.0
        if int(t) % 2 == 0:
            s += 2 * 0.12 * v
        assert w.check(t, s) is None, (t, s)
    assert t > 2 * old_limit_s(length, v)  # the old limit would have ended it halfway
    assert t < w.cap_s


def test_a_stalled_trial_times_out_with_the_stall_detail():
    """The tool progresses at 1.5 mm/s to s = 300 mm (t = 200 s), then stands: the trial ends
    when a whole 30 s window shows less than 2 mm, not before, and says so."""
    w = ProgressLimit().watch(700.0, 4.0)
    for k in range(1, 201):
        assert w.check(float(k), 1.5 * k) is None
    fired = None
    for k in range(201, 400):
        why = w.check(float(k), 300.0 + 0.01 * (k - 200))  # creeping 0.01 mm/s: a stall
        if why is not None:
            fired = k, why
            break
    assert fired is not None
    k, why = fired
    assert 225 <= k <= 231  # the window still held progress until 30 s after the stop
    assert why.startswith("stall:") and "in the last 30 s" in why and "(< 2 mm)" in why and "s 300." in why


def test_the_hard_cap_ends_a_trial_that_creeps_on_and_says_so():
    w = ProgressLimit().watch(100.0, 4.0)  # cap 12 x 100 / 4 + 60 = 360 s
    assert w.cap_s == pytest.approx(360.0)
    for k in range(1, 360):
        assert w.check(float(k), 0.1 * k) is None  # 3 mm a window: slow, but not a stall
    why = w.check(360.0, 36.0)
    assert why is not None and why.startswith("hard cap:") and "360 s" in why and "12 x 100 mm / 4 mm/s + 60 s" in why


def test_no_reading_of_the_seam_for_a_whole_window_is_a_stall_and_a_slow_command_a_smaller_minimum():
    w = ProgressLimit().watch(700.0, 16.0)
    whys = [w.check(float(k), math.nan) for k in range(1, 32)]
    assert whys[:29] == [None] * 29 and any(why and why.startswith("stall:") for why in whys)
    # a commanded 0.5 mm/s covers 15 mm a window: the minimum is 5 % of it, 0.75 mm, not 2 mm
    assert ProgressLimit().min_progress_mm(0.5) == pytest.approx(0.75)
    assert ProgressLimit().min_progress_mm(4.0) == pytest.approx(2.0)


def fast_trial(limit):
    return run_trial(TrialConfig("limit", "i", 16.0, length_mm=300.0, arm="fast", holder="fixed",
                                 sensor="ideal"), limit=limit)


def test_the_lockstep_trial_ends_on_the_stall_rule_with_its_detail():
    """The rule wired into run_trial: a 5 s window that asks for 1000 mm can only stall (the fast
    arm's tool moves ~7.5 mm/s); the trial ends at 5-6 s as timeout, where the tool was."""
    r = fast_trial(ProgressLimit(window_s=5.0, min_mm=1000.0, min_fraction=100.0))
    assert r.stop_reason == "timeout", (r.stop_reason, r.stop_detail)
    assert r.stop_detail.startswith("stall:") and "in the last 5 s" in r.stop_detail
    assert 5.0 <= r.stop_t_s <= 6.5
    assert 0.0 < r.stop_s_mm < 100.0
    # the same trial with the default limit tracks to its end
    assert fast_trial(ProgressLimit()).stop_reason == "end of seam"


def test_the_lockstep_trial_ends_on_the_hard_cap_with_its_detail():
    r = fast_trial(ProgressLimit(cap_factor=0.0, cap_extra_s=8.0))
    assert r.stop_reason == "timeout" and r.stop_detail.startswith("hard cap: no end within 8 s"), r.stop_detail
    assert 8.0 <= r.stop_t_s <= 9.5
