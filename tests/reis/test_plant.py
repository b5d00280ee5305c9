"""The simulated Reis robot behind the register map (thesis §2.3, §4.1.2)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.subunits.reis import vme_map as vm
from droid.subunits.reis.vme import VmeBus

DT = 0.002  # one servo period


def run_open_loop(plant: ReisPlant, bus: VmeBus, dacs, seconds: float, kick: bool = True) -> None:
    for _ in range(int(round(seconds / DT))):
        bus.write_dacs(dacs)
        if kick:
            bus.kick_watchdog()
        plant.advance(DT)


@pytest.fixture
def rig():
    plant = ReisPlant(seed=11)
    bus = VmeBus.from_buffer(plant.regs)
    yield plant, bus
    bus.close()


def test_power_up_counters_are_arbitrary_per_seed_and_deterministic():
    a, b, c = ReisPlant(seed=1), ReisPlant(seed=1), ReisPlant(seed=2)
    assert a.encoder_raw == b.encoder_raw
    assert a.encoder_raw != c.encoder_raw
    assert all(0 <= x < 65536 for x in a.encoder_raw)
    assert np.array_equal(a.joint_deg, b.joint_deg)


def test_registers_mirror_the_state(rig):
    plant, bus = rig
    assert bus.read_encoders_raw() == plant.encoder_raw
    assert bus.read_limit_switches() == plant.limit_switches
    assert bus.read_amp_status() == 0  # amplifiers off until the watchdog runs
    bus.kick_watchdog()
    plant.advance(DT)
    assert bus.read_amp_status() == vm.AMP_STATUS_POWERED


def test_amplifiers_power_up_only_once_both_watchdogs_are_written(rig):
    plant, bus = rig
    run_open_loop(plant, bus, [2047] * 6, 0.5, kick=False)  # no watchdog program yet
    assert not plant.amps_on and np.all(plant.motor_speed_counts_per_s == 0)
    bus.write_watchdog(1, 0)  # only register 0 changed
    plant.advance(DT)
    assert not plant.amps_on
    bus.write_watchdog(2, 1)
    plant.advance(DT)
    assert plant.amps_on


def test_encoder_counts_motor_side_4000_per_rev_through_the_gearing():
    plant = ReisPlant(seed=3, initial_joint_deg=np.zeros(6), encoder_power_up_counts=[0] * 6)
    bus = VmeBus.from_buffer(plant.regs)
    c0 = np.floor(plant.motor_counts[5])  # the motor holds the sensor head's weight: not exactly 0
    q0 = plant.motor_joint_deg[5]
    run_open_loop(plant, bus, [0, 0, 0, 0, 0, 1500], 0.3)
    q6 = plant.motor_joint_deg[5]  # the encoders sit on the motors (motor side)
    assert q6 - q0 > 1.0  # joint 6 turned
    # counts = M q: 100:1 drive x 4000 counts / 360 deg on joint 6 (no coupling)
    assert bus.read_encoders_raw()[5] == int(np.floor(q6 * 100 * 4000 / 360) - c0) % 65536
    # the link follows the motor through the harmonic drive (deflection, not slip)
    assert abs(q6 - plant.joint_deg[5]) < 0.5
    bus.close()


def test_encoders_wrap_at_16_bits():
    plant = ReisPlant(seed=3, encoder_power_up_counts=[65000] * 6)
    bus = VmeBus.from_buffer(plant.regs)
    assert bus.read_encoders_raw() == (65000,) * 6
    start = np.floor(plant.motor_counts[5])
    run_open_loop(plant, bus, [0, 0, 0, 0, 0, 2047], 0.3)
    moved = np.floor(plant.motor_counts[5]) - start
    assert moved > 1000  # more than the 536 counts left below 65536
    assert bus.read_encoders_raw()[5] == (65000 + int(moved)) % 65536
    assert bus.read_encoders_raw()[5] < 65000
    bus.close()


def test_writing_an_encoder_register_resets_that_counter(rig):
    plant, bus = rig
    before = bus.read_encoders_raw()
    bus.write_u16(vm.ENCODER_OFFSET + 2, 12345)  # any write resets to 0 (thesis §4.1.2)
    plant.advance(DT)
    after = bus.read_encoders_raw()
    assert after[1] in (0, 65535)
    assert after[0] == before[0]


def test_positive_dac_accelerates_and_saturates():
    params = ReisPlantParams()
    base = ReisPlant(params, seed=5)
    speeds = []
    for dac in (500, 1000, 2047, 30000):
        plant = ReisPlant(params, seed=5)
        bus = VmeBus.from_buffer(plant.regs)
        run_open_loop(plant, bus, [0, 0, 0, dac, 0, 0], 0.05)
        speeds.append(plant.motor_speed_counts_per_s[3])
        bus.close()
    assert 0 < speeds[0] < speeds[1] < speeds[2]
    assert speeds[3] == speeds[2]  # the driver clamps to 2047, the amplifier limits torque
    assert base.motor_speed_counts_per_s[3] == 0


def test_coulomb_friction_holds_against_a_small_command():
    # at the zero pose gravity loads joints 2, 3 and 5 only (wrist bent horizontal)
    plant = ReisPlant(seed=5, initial_joint_deg=np.zeros(6))
    bus = VmeBus.from_buffer(plant.regs)
    q0 = plant.joint_deg.copy()
    run_open_loop(plant, bus, [20, 0, 0, 20, 0, 20], 0.2)  # torques below Coulomb friction
    # (the links may move by the drives' deflection as the others sag: < 0.01 deg)
    assert np.allclose(plant.joint_deg[[0, 3, 5]], q0[[0, 3, 5]], atol=1e-2)
    assert np.all(plant.motor_speed_counts_per_s[[0, 3, 5]] == 0)
    run_open_loop(plant, bus, [300, 0, 0, 300, 0, 300], 0.2)  # above it: they turn
    assert np.all(np.abs(plant.joint_deg[[0, 3, 5]] - q0[[0, 3, 5]]) > 0.1)
    bus.close()


def test_gravity_pulls_the_forearm_down_and_the_balancer_helps_joint_2():
    """With zero DAC the unbalanced joint 3 load exceeds friction: the arm sags."""
    plant = ReisPlant(seed=5, initial_joint_deg=np.zeros(6))
    bus = VmeBus.from_buffer(plant.regs)
    run_open_loop(plant, bus, [0] * 6, 0.3)
    assert plant.joint_deg[2] < -1.0  # forearm falls (positive q3 raises it, D-H Table 4.1)
    tau = plant.gravity_joint_torque_nm(np.zeros(6))
    assert tau[2] < 0 and abs(tau[0]) < 1e-9  # joint 1's axis is vertical: no gravity torque
    no_balancer = ReisPlant(replace(ReisPlantParams(), balancer=False), seed=5)
    tau2_raw = no_balancer.gravity_joint_torque_nm(np.array([0, 60.0, 0, 0, 0, 0]))[1]
    tau2_bal = plant.gravity_joint_torque_nm(np.array([0, 60.0, 0, 0, 0, 0]))[1]
    assert 0 < tau2_bal < tau2_raw
    # the load follows the configuration: the forearm's moment about joint 3 is largest horizontal
    assert abs(plant.gravity_joint_torque_nm(np.array([0, 0, 60.0, 0, 0, 0]))[2]) < abs(tau[2])
    bus.close()


def test_limit_switch_is_a_cam_active_past_its_position():
    params = ReisPlantParams()
    sw = np.array(params.switch_joint_deg)
    plant = ReisPlant(params, seed=0, initial_joint_deg=sw + np.array([0.1, -0.1, 0.1, -0.1, 5.0, -5.0]))
    assert plant.limit_switches == (True, False, True, False, True, False)
    assert VmeBus.from_buffer(plant.regs).read_limit_bits() == 0b010101


def test_watchdog_latch_cuts_the_amplifiers_until_power_cycle(rig):
    plant, bus = rig
    run_open_loop(plant, bus, [0] * 6, 0.05)
    assert plant.amps_on
    run_open_loop(plant, bus, [0] * 6, 0.098, kick=False)  # < 100 ms without a kick: still on
    assert plant.amps_on
    run_open_loop(plant, bus, [0] * 6, 0.01, kick=False)
    assert not plant.amps_on
    assert bus.read_amp_status() == vm.AMP_STATUS_WATCHDOG_FAULT
    run_open_loop(plant, bus, [0] * 6, 1.0, kick=False)  # the brake stops the sagging arm; the links ring out
    assert np.all(plant.motor_speed_counts_per_s == 0)
    q = plant.joint_deg.copy()
    m = plant.motor_counts.copy()
    run_open_loop(plant, bus, [2047] * 6, 0.3, kick=True)  # kicking again does not help
    assert not plant.amps_on
    assert np.array_equal(plant.motor_counts, m)  # brakes hold the motors, DACs ignored
    assert np.allclose(plant.joint_deg, q, atol=0.05)  # the links ring out on the drives' stiffness
    raw_before = bus.read_encoders_raw()
    plant.power_cycle()
    assert not plant.amps_on  # powered again once the watchdog is kicked
    run_open_loop(plant, bus, [0] * 6, 0.004)
    assert plant.amps_on
    assert bus.read_amp_status() == vm.AMP_STATUS_POWERED
    assert bus.read_dacs() == (0,) * 6
    assert bus.read_encoders_raw() != raw_before  # counters come up arbitrary again


def test_one_stuck_watchdog_register_is_enough_to_trip(rig):
    plant, bus = rig
    for i in range(80):
        bus.write_watchdog(i, 7)  # register 1 never changes
        plant.advance(DT)
    assert not plant.amps_on


def test_jam_blocks_a_motor(rig):
    plant, bus = rig
    plant.jam(0)
    m0 = plant.motor_counts[0]
    run_open_loop(plant, bus, [2047, 0, 0, 0, 0, 0], 0.2)
    assert plant.motor_counts[0] == m0
    plant.jam(0, False)
    run_open_loop(plant, bus, [2047, 0, 0, 0, 0, 0], 0.05)
    assert plant.motor_counts[0] > m0


def test_advance_needs_whole_substeps(rig):
    plant, _ = rig
    with pytest.raises(ValueError):
        plant.advance(0.0007)
    with pytest.raises(ValueError):
        plant.advance(0.0)


def test_same_seed_same_trajectory():
    def trace(seed):
        plant = ReisPlant(seed=seed)
        bus = VmeBus.from_buffer(plant.regs)
        out = []
        for i in range(200):
            bus.write_dacs([int(800 * np.sin(i / 20 + j)) for j in range(6)])
            bus.kick_watchdog()
            plant.advance(DT)
            out.append(bytes(plant.regs))
        return out

    assert trace(9) == trace(9)
    assert trace(9) != trace(10)


def test_hard_stop_holds_a_joint_driven_into_it():
    params = ReisPlantParams()
    q0 = np.zeros(6)
    q0[0] = params.hard_stop_min_deg[0] + 2.0
    plant = ReisPlant(params, seed=1, initial_joint_deg=q0)
    bus = VmeBus.from_buffer(plant.regs)
    run_open_loop(plant, bus, [1500, 0, 0, 0, 0, 0], 0.5)  # joint 1 counts run opposite to q1
    assert params.hard_stop_min_deg[0] - 0.5 <= plant.joint_deg[0] <= params.hard_stop_min_deg[0]
    assert plant.motor_speed_counts_per_s[0] == 0
    run_open_loop(plant, bus, [-1500, 0, 0, 0, 0, 0], 0.1)  # and it can drive away again
    assert plant.joint_deg[0] > params.hard_stop_min_deg[0] + 0.5
    bus.close()


def test_an_arm_at_rest_with_unchanged_inputs_is_not_integrated_and_gives_the_same_bits():
    """The rest shortcut of advance (droid-sim's idle cell) changes no bit: a plant that never
    takes it, stepped beside one that does through holding, a jog from rest, holding again and
    a watchdog latch, has the same registers and state after every 50 ms."""
    from droid.sim.reis.lockstep import NEAR_SWITCH_OFFSET_DEG, constant_commander, make_reis_cell
    from droid.subunits.reis.servo_params import Mode

    params = ReisPlantParams(compliance=False)  # droid-sim's default cell (compliant links never rest to the bit)
    cells = [make_reis_cell(seed=21, near_switch_offset_deg=NEAR_SWITCH_OFFSET_DEG, plant_params=params)
             for _ in range(2)]
    cells[1].plant._rest_key = lambda n: None  # never at rest: every advance integrated
    plants = [c.plant for c in cells]

    def run(seconds, commander=None):
        for _ in range(int(round(seconds / 0.05))):
            for c in cells:
                c.run(0.05, commander, record=False)
            a, b = plants
            assert bytes(a.regs) == bytes(b.regs) and a.time_s == b.time_s
            for k in ("_theta", "_omega", "_q", "_qd"):
                assert getattr(a, k).tobytes() == getattr(b, k).tobytes(), k

    run(1.0)  # the servo holds the arm where it powered up
    held = plants[0].rest_steps
    assert held > 0 and plants[1].rest_steps == 0
    q_rest = plants[0].joint_deg
    run(0.5, constant_commander(Mode.JOG, (0, 0, 0, 0, 0, 40)))  # the servo's DACs start joint 6 from rest
    assert abs(plants[0].joint_deg[5] - q_rest[5]) > 0.1
    run(1.0, constant_commander(Mode.JOG))  # and hold it again
    assert plants[0].rest_steps > held
    rested = plants[0].rest_steps
    for write in (False, False, True, False):  # an encoder register written at rest resets its counter
        for c in cells:
            if write:
                c.bus.write_u16(vm.ENCODER_OFFSET + 4, 1234)
            c.plant.advance(DT)
        assert bytes(plants[0].regs) == bytes(plants[1].regs)
    assert plants[0].rest_steps >= rested + 3
    run(0.2)
    for c in cells:  # the watchdog stops kicking: the amplifiers latch off, the brakes hold
        c.watchdog_running = False
    run(1.0)
    assert not plants[0].amps_on
    for c in cells:
        c.close()
