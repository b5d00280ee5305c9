"""A lockstep trial ends as ``fault`` when the Reis faults mid-trial (issue 16 item 2).

Before, trial 2.5's Reis faulted (Status fault 20: servo + braking, then 22: + watchdog,
amplifiers latched off) at t = 17 s and the tracker commanded the stopped arm until the
stall rule ended the trial at 48 s as ``timeout``.  Here a fault is injected into the
full Reis model -- droid-servo stops (``LockstepArm.alive["servo"] = False``, as a killed
or hung servo program): the servo agent reports FAULT_SERVO and the watchdog latches the
amplifiers off -- and the trial must end as ``fault`` naming arm1 and its faults, at the
first 30 Hz cycle that reads the fault in the Status, with no command written after it.
The holder's Status goes through the same rule: a GMF1 whose serial port vanishes
(FAULT_DEVICE) ends the trial naming gmf1 (without the rule that trial runs to its end:
the stop is conservative -- the Brain no longer knows the holder's controller state).
"""
from __future__ import annotations

import pytest

from droid.brain.db.layouts import FAULTS_CANNOT_MOVE
from droid.sim import trial_cell
from droid.experiments.trial import CYCLE_TICKS, TrialConfig, run_trial
from droid.sim.lockstep import ORDER_TASK

#: Injected this many heartbeat ticks into the trial (after the 1 s dead zone) [ticks].
INJECT_TICK = 240
#: Stated promptness: the trial stops within this many 30 Hz cycles after the fault bit
#: first shows in the Reis Status the tracker reads (the rule runs before every cycle).
STOP_WITHIN_CYCLES = 1


class InjectedArm(trial_cell.FullArm):
    """The full Reis whose servo program stops ``INJECT_TICK`` ticks into the trial; records
    what the Status showed after each tick's task and every command the trial wrote."""

    def __init__(self, sched, *a, **kw) -> None:
        super().__init__(sched, *a, **kw)
        self.trial_ticks = 0  # ticks since the trial's clock started (tick() runs from then on)
        self.fault_seen: int | None = None  # first trial tick whose Status has a stopping fault
        self.fault_bits = 0
        self.commands: list[int] = []  # trial ticks of the cartesian commands
        sched.on_tick(self._after_task, "fault watch", order=ORDER_TASK + 1)

    def tick(self) -> None:
        self.trial_ticks += 1
        if self.trial_ticks == INJECT_TICK:
            self.arm.alive["servo"] = False

    def _after_task(self, tick: int) -> None:
        bits = int(self.arm.status["fault"])
        if self.trial_ticks and self.fault_seen is None and bits & FAULTS_CANNOT_MOVE:
            self.fault_seen, self.fault_bits = self.trial_ticks, bits

    def command_cart(self, T, ticks: int) -> None:
        self.commands.append(self.trial_ticks)
        super().command_cart(T, ticks)


@pytest.fixture
def injected(monkeypatch):
    made = []

    class Arm(InjectedArm):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            made.append(self)

    monkeypatch.setattr(trial_cell, "FullArm", Arm)
    return made


def test_a_reis_fault_mid_trial_ends_it_as_fault_at_once_and_nothing_is_commanded_after(injected):
    r = run_trial(TrialConfig("inject", "i", 16.0, length_mm=300.0, sensor="ideal", seed=3))
    (arm,) = injected
    assert arm.fault_seen is not None and arm.fault_seen > INJECT_TICK  # the fault reached the Status
    assert r.stop_reason == "fault", (r.stop_reason, r.stop_detail)
    assert r.stop_detail.startswith("arm1 faults: ") and "servo" in r.stop_detail, r.stop_detail
    # promptly: the trial's clock stopped within one cycle of the first Status with the fault
    stop_tick = round(r.stop_t_s * 60.0)
    assert 0 <= stop_tick - arm.fault_seen <= STOP_WITHIN_CYCLES * CYCLE_TICKS, (stop_tick, arm.fault_seen)
    # the arm was commanded up to the fault and never after it
    assert len(arm.commands) > 100 and max(arm.commands) < arm.fault_seen
    assert r.stop_t_s < 10.0  # long before any stall rule (30 s without progress)


def test_a_holder_fault_ends_the_trial_naming_the_gmf1(monkeypatch):
    """The GMF1's serial port vanishes mid-trial (FAULT_DEVICE in its Status, docs/gmf1.md): the
    trial ends as ``fault`` naming gmf1 -- the holder's Status goes through the same rule."""
    from droid.sim.gmf1 import holder as holder_mod

    made = []

    class Holder(holder_mod.Gmf1Holder):
        def __init__(self, sched, *a, **kw):
            super().__init__(sched, *a, **kw)
            self.trial_ticks = None  # counting from the end of prepare()
            sched.on_tick(self._count, "port fault", order=ORDER_TASK + 1)
            made.append(self)

        def prepare(self):
            super().prepare()
            self.trial_ticks = 0

        def _count(self, tick):
            if self.trial_ticks is None:
                return
            self.trial_ticks += 1
            if self.trial_ticks == INJECT_TICK:
                self.g.pair.vanish()

    monkeypatch.setattr(holder_mod, "Gmf1Holder", Holder)
    r = run_trial(TrialConfig("inject-holder", "i", 16.0, length_mm=300.0, sensor="ideal", seed=3, arm="fast"))
    assert made and r.stop_reason == "fault", (r.stop_reason, r.stop_detail)
    assert r.stop_detail.startswith("gmf1 faults: ") and "device" in r.stop_detail, r.stop_detail
    assert INJECT_TICK / 60.0 < r.stop_t_s < INJECT_TICK / 60.0 + 1.0
