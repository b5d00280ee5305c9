"""The protective stop keeps the separation on head-on and crossing courses (issue 41; lockstep).

A seeded subset of bench/bench_guard_trials.py's 200: the reis_pair cell in lockstep with the
guard's station, the real planners, servos and plants; the verdict at the plants' true angles.
"""
from __future__ import annotations

import pytest

from droid.experiments.guard_trial import GuardTrials


@pytest.fixture(scope="module")
def trials():
    t = GuardTrials()
    yield t
    t.close()


@pytest.mark.parametrize("kind,seed", [("head-on", 0), ("crossing", 0), ("head-on", 9), ("crossing", 5)])
def test_the_guard_keeps_the_stated_separation(trials, kind, seed):
    r = trials.run(kind, seed)
    assert r.unguarded_min_mm < r.limit_mm  # the course would have broken the limit unguarded
    assert not r.servo_fault, r
    assert r.stopped, r
    assert r.kept, r  # the least true distance over the trial stayed above the stated limit
