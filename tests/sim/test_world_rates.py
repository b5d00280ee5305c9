"""droid-sim's world steps each device at its own rate (Device.step_s, issue 40 item 2): a device
with a rate of its own is advanced only every step_s of world time, by all the time it is owed,
and every device on the world's first step."""
from __future__ import annotations

import pytest

from droid.sim.device import Device
from droid.sim.world import World


class Counting(Device):
    def __init__(self, name: str, step_s: float) -> None:
        self.name, self.step_s, self.calls = name, step_s, []

    def advance(self, dt_s: float) -> None:
        self.calls.append(dt_s)


@pytest.mark.parametrize("step_s, steps", [(0.0, 10), (0.002, 9), (0.004, 13), (0.01, 37)])
def test_a_device_is_advanced_every_step_s_with_all_the_time_it_is_owed(step_s, steps):
    world = World(cell=None)
    dev = Counting("d", step_s)
    world.add("d", dev)
    for _ in range(steps):
        world.advance(0.001)
    per_call = max(1, round(step_s / 0.001))
    assert dev.calls[0] == 0.001  # the first step: power-up
    assert all(dt == pytest.approx(per_call * 0.001, abs=1e-12) for dt in dev.calls[1:])
    assert len(dev.calls) == 1 + (steps - 1) // per_call
    owed = (steps - 1) % per_call * 0.001
    assert sum(dev.calls) + owed == pytest.approx(steps * 0.001, abs=1e-12)  # no world time lost
    assert world.t_s == pytest.approx(steps * 0.001)


def test_the_built_in_twins_declare_their_rates():
    from droid.sim.gmf1.karel import KarelDevice
    from droid.sim.mvs.devices import MvsCameraDevice, ToolSensorDevice
    from droid.sim.reis.world import ReisDevice
    from droid.sim.serial_cable import SerialCable

    assert ReisDevice.step_s == 0.0  # the servo reads the register map at 500 Hz: every 1 ms step
    assert KarelDevice.step_s == 0.002
    assert MvsCameraDevice.step_s == ToolSensorDevice.step_s == SerialCable.step_s == 0.004


def test_the_worlds_step_times_give_quantiles_max_and_late_wake_ups():
    from droid.sim.world import StepTimes

    st = StepTimes()
    assert st.summary() == "0 wake-ups: steps p50 0 us, p99 0 us, max 0 us; 0 woke >= 20 ms late"
    for k in range(1000):
        st.add(35_000 if k < 990 else 2_000_000, 25_000_000 if k == 999 else 100_000)
    assert st.quantile_us(0.5) == 40.0 and st.quantile_us(0.99) == 40.0 and st.quantile_us(0.995) == 2010.0
    assert st.summary() == "1000 wake-ups: steps p50 40 us, p99 40 us, max 2000 us; 1 woke >= 20 ms late"
    st.add(10**12, 0)  # beyond the last bin: counted there, the max exact
    assert st.hist[-1] == 1 and st.max_ns == 10**12
