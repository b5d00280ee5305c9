"""droid-sim's real-time loop on a fake timer (issue 40 item 2): the world wakes at the fastest
rate its devices need (World.steps_per_wake: the servo's 500 Hz for an arm twin), takes the
world steps in between back to back, and after a stall catches up exactly and boundedly
(CatchUp): every period's steps are taken or, beyond MAX_OWED_S, counted as slipped; no wake-up
takes more than CATCH_UP_PERIODS of its periods; a plant that caught up holds the bits of one
that never stalled."""
from __future__ import annotations

import io
import random

import numpy as np
import pytest

from droid.sim.device import Device, wake_hz_of
from droid.sim.world import CATCH_UP_PERIODS, MAX_OWED_S, CatchUp, StepTimes, World, serve


class Counting(Device):
    def __init__(self, name: str, step_s: float = 0.0, wake_hz=None) -> None:
        self.name, self.step_s, self.wake_hz, self.calls = name, step_s, wake_hz, []

    def advance(self, dt_s: float) -> None:
        self.calls.append(dt_s)


class FakeTimer:
    """A PeriodicTimer's face on a script: each wait() returns the next count of periods
    elapsed (0: a timeout), with the cycle count and a lateness the loop records."""

    def __init__(self, script) -> None:
        self.script = list(script)
        self.cycles = 0
        self.lateness_ns = 0
        self.waits = 0

    def wait(self, timeout_s=None) -> int:
        self.waits += 1
        n = self.script.pop(0)
        if n:
            self.cycles += 1
            self.lateness_ns = (n - 1) * 2_000_000
        return n


class FakeClock:
    def __init__(self) -> None:
        self.t = 0

    def __call__(self) -> int:
        self.t += 1000
        return self.t


def run_script(world, script, spw, per_wake=None, max_owed=None, dt_s=0.001):
    timer = FakeTimer(script)
    per_wake = CATCH_UP_PERIODS * spw if per_wake is None else per_wake
    max_owed = max(per_wake, int(MAX_OWED_S / dt_s)) if max_owed is None else max_owed
    catch_up = CatchUp(spw, per_wake, max_owed)
    taken, beats, log = [], [], io.StringIO()
    steps_fn = world.steps

    def steps(n, dt):
        taken.append(n)
        steps_fn(n, dt)
    world.steps = steps
    st = StepTimes()
    serve(world, timer, catch_up, dt_s, st, stop=lambda: not timer.script, beat=lambda: beats.append(timer.cycles),
          clock_ns=FakeClock(), log=log)
    return catch_up, taken, beats, log.getvalue(), st


# -- the wake-up rate -----------------------------------------------------------------------

def test_the_world_wakes_at_the_fastest_rate_its_devices_need():
    w = World(cell=None)
    assert w.steps_per_wake(1000.0) == 1  # no device: every step
    w.add("cam", Counting("cam", step_s=0.004))
    assert w.steps_per_wake(1000.0) == 4  # a 4 ms device alone: every 4 ms
    w.add("karel", Counting("karel", step_s=0.002))
    assert w.steps_per_wake(1000.0) == 2
    w.add("arm", Counting("arm", step_s=0.0, wake_hz=500.0))  # read at 500 Hz, stepped every 1 ms
    assert w.steps_per_wake(1000.0) == 2
    assert w.steps_per_wake(2000.0) == 4
    assert w.steps_per_wake(500.0) == 1
    assert w.steps_per_wake(300.0) == 1  # never fewer wake-ups than the world's steps allow
    w.add("odd", Counting("odd", wake_hz=300.0))
    assert w.steps_per_wake(1000.0) == 2  # 500 Hz still needed
    w.add("every", Counting("every"))  # step_s 0, no wake_hz: every world step
    assert w.steps_per_wake(1000.0) == 1
    w2 = World(cell=None)
    w2.add("odd", Counting("odd", wake_hz=300.0))
    assert w2.steps_per_wake(1000.0) == 3  # 333 Hz >= 300 Hz


def test_a_devices_wake_rate_is_its_own_or_its_step_and_never_above_the_worlds():
    assert wake_hz_of(Counting("a"), 1000.0) == 1000.0
    assert wake_hz_of(Counting("a", step_s=0.01), 1000.0) == pytest.approx(100.0)
    assert wake_hz_of(Counting("a", wake_hz=5000.0), 1000.0) == 1000.0
    assert wake_hz_of(Counting("a", step_s=0.004, wake_hz=500.0), 1000.0) == 500.0


def test_the_built_in_twins_need_the_world_at_the_servos_rate_at_most():
    from droid.sim.ft.netft import NetFtTwinDevice
    from droid.sim.gmf1.karel import KarelDevice
    from droid.sim.mvs.arm import FixedArm
    from droid.sim.mvs.devices import MvsCameraDevice, ToolSensorDevice
    from droid.sim.reis.world import ReisDevice
    from droid.sim.serial_cable import SerialCable
    from droid.subunits.reis.device import SERVO_HZ

    assert ReisDevice.wake_hz == SERVO_HZ == 500.0 and ReisDevice.step_s == 0.0  # still stepped every 1 ms
    assert FixedArm.wake_hz == 0.0
    w = World(cell=None)
    for cls in (KarelDevice, MvsCameraDevice, ToolSensorDevice, SerialCable, ReisDevice, FixedArm):
        dev = Counting(cls.__name__, cls.step_s, cls.wake_hz)
        assert wake_hz_of(dev, 1000.0) <= 500.0
        w.add(dev.name, dev)
    assert NetFtTwinDevice.wake_hz is None  # its step is set per twin (the RDT period, at most 4 ms)
    assert w.steps_per_wake(1000.0) == 2


def test_steps_are_world_steps_back_to_back():
    w1, w2 = World(cell=None), World(cell=None)
    for w in (w1, w2):
        for name, step_s in (("arm", 0.0), ("cam", 0.004), ("karel", 0.002)):
            w.add(name, Counting(name, step_s))
    for _ in range(17):
        w1.advance(0.001)
    w2.steps(5, 0.001)
    w2.steps(12, 0.001)
    for name in ("arm", "cam", "karel"):
        assert w1.devices[name].calls == w2.devices[name].calls
    assert w1.t_s == w2.t_s


# -- the catch-up -------------------------------------------------------------------------

def test_no_stall_takes_the_wake_ups_steps_each_time():
    w = World(cell=None)
    arm = Counting("arm", wake_hz=500.0)
    w.add("arm", arm)
    catch_up, taken, beats, log, st = run_script(w, [1] * 50 + [0] + [1] * 50, spw=2)
    assert taken == [2] * 100  # a timeout (0) takes nothing
    assert len(arm.calls) == 200 and set(arm.calls) == {0.001}
    assert catch_up.slipped == 0 and catch_up.owed == 0 and catch_up.taken == 200
    assert beats == list(range(1, 101)) and st.n == 100 and log == ""


def test_a_stall_is_caught_up_exactly_and_boundedly():
    w = World(cell=None)
    arm = Counting("arm", wake_hz=500.0)
    w.add("arm", arm)
    stall = 30  # 60 ms of 2 ms periods: within MAX_OWED_S
    script = [1] * 10 + [stall] + [1] * 40
    catch_up, taken, _, log, _ = run_script(w, script, spw=2)
    per_wake = CATCH_UP_PERIODS * 2
    assert max(taken) == per_wake  # bounded: never the whole stall in one wake-up
    assert sum(taken) == 2 * sum(script) == len(arm.calls)  # exact: nothing lost, nothing added
    assert catch_up.slipped == 0 and catch_up.owed == 0 and log == ""
    # it gains (per_wake - 2) steps a wake-up until the debt is paid, then takes 2 again
    debt = 2 * stall - per_wake
    catching = -(-debt // (per_wake - 2))
    assert taken[11:11 + catching - 1] == [per_wake] * (catching - 1)
    assert taken[11 + catching:] == [2] * (len(taken) - 11 - catching)


def test_a_stall_beyond_max_owed_slips_the_clock_once_and_says_so():
    w = World(cell=None)
    w.add("arm", Counting("arm", wake_hz=500.0))
    script = [1] * 5 + [200] + [1] * 60 + [150] + [1] * 5  # 400 ms, then 300 ms
    max_owed = 100
    catch_up, taken, _, log, _ = run_script(w, script, spw=2, max_owed=max_owed)
    assert catch_up.slipped > 0
    assert sum(taken) + catch_up.owed + catch_up.slipped == 2 * sum(script)
    assert max(taken) == 8
    lines = log.splitlines()
    assert len(lines) == 1  # the second stall came within a second of wake-ups of the first
    assert lines[0].startswith("droid-sim: stalled 400 ms at wake-up 6: the world's clock slipped ")
    assert f"slipped {2 * 200 - max_owed} ms" in lines[0]


@pytest.mark.parametrize("seed", range(5))
def test_the_catch_up_accounts_for_every_period_on_random_stalls(seed):
    rng = random.Random(seed)
    spw = rng.choice([1, 2, 4])
    per_wake = spw * rng.choice([1, 2, 4])
    max_owed = per_wake + rng.randrange(0, 120)
    c = CatchUp(spw, per_wake, max_owed)
    periods = 0
    for _ in range(2000):
        n = rng.choice([1] * 20 + [2, 3, 10, 60])
        owed_before = c.owed
        k, dropped = c.wake(n)
        periods += n
        assert 0 <= k <= per_wake and 0 <= c.owed <= max_owed - k + (k if dropped == 0 else 0)
        assert dropped == max(0, owed_before + n * spw - max_owed)  # only what is beyond max_owed
        assert k == min(per_wake, owed_before + n * spw - dropped)  # all it may, up to per_wake
        assert c.taken + c.owed + c.slipped == spw * periods


def test_a_catch_up_is_refused_bad_bounds():
    for args in ((0, 4, 100), (2, 1, 100), (2, 8, 4)):
        with pytest.raises(ValueError, match="steps_per_wake"):
            CatchUp(*args)
    assert CatchUp.for_rate(1000.0, 2).per_wake == 2 * CATCH_UP_PERIODS
    assert CatchUp.for_rate(1000.0, 2).max_owed == int(MAX_OWED_S * 1000)


class PlantDevice(Device):
    """A Reis plant stepped as the world steps an arm twin (its register map in memory), its
    watchdog registers kicked every 20 world steps (as droid-watchdog does at 50 Hz)."""
    wake_hz = 500.0

    def __init__(self, plant) -> None:
        import struct

        from droid.subunits.reis import vme_map as vm

        self.name, self.plant, self.k = "arm", plant, 0
        self._kick = lambda v: struct.pack_into("<2H", plant.regs, vm.WATCHDOG_OFFSETS[0], v, v)

    def advance(self, dt_s: float) -> None:
        if self.k % 20 == 0:
            self._kick(self.k // 20 % 65536)
        self.k += 1
        self.plant.advance(dt_s)


def _plant_world():
    from droid.sim.reis.plant import ReisPlant, ReisPlantParams
    from droid.subunits.reis import vme_map as vm

    plant = ReisPlant(ReisPlantParams(robot="reis_v15"), seed=3)
    w = World(cell=None)
    w.add("arm", PlantDevice(plant))
    # the amplifiers on and drives turning (DAC words, as the servo writes them), every period
    view = memoryview(plant.regs)
    return w, plant, view, vm


def test_a_plant_that_caught_up_holds_the_bits_of_one_that_never_stalled():
    script = [1] * 20 + [25] + [1] * 40 + [3] + [1] * 20
    stalled, p1, v1, vm = _plant_world()
    steady, p2, v2, _ = _plant_world()
    dac = np.array([900, -700, 1200, -400, 300, -250], dtype="<i2").tobytes()
    for v in (v1, v2):
        v[vm.DAC_OFFSET:vm.DAC_OFFSET + len(dac)] = dac
    stalled.advance(0.001)
    steady.advance(0.001)
    catch_up, taken, _, _, _ = run_script(stalled, script, spw=2)
    assert catch_up.slipped == 0 and catch_up.owed == 0
    for _ in range(catch_up.taken):
        steady.advance(0.001)
    assert p1.time_s == p2.time_s == pytest.approx(0.001 * (1 + 2 * sum(script)))
    assert bytes(p1.regs) == bytes(p2.regs)
    for k in ("_theta", "_omega", "_q", "_qd"):
        assert np.asarray(getattr(p1, k)).tobytes() == np.asarray(getattr(p2, k)).tobytes()
    assert p1.amps_on and np.any(p1.motor_speed_counts_per_s != 0.0)  # it moved: the comparison means something
