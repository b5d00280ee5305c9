"""The compiled kernel (issue 28 item 1, droid/_kernel.c) against the Python reference, bit for bit.

The tolerance is zero: the kernel performs the reference's IEEE operations in the reference's
order and calls numpy's own cblas_dgemv (droid.kernel), so every step of the plant's exact
integrator and every PID tick (thesis §4.1.5.1) must give the same bits.  The kernel is built by
``pip install -e .`` (setup.py); these tests fail, not skip, when it is missing.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from droid import kernel
from droid.sim.reis.lockstep import ReisLockstep, drive_side_by_side, plants_same_bits
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.subunits.reis import vme_map as vm
from droid.subunits.reis.pid import Pid
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.servo_params import Mode

ROOT = Path(__file__).resolve().parents[2]
STATE = ("_theta", "_omega", "_q", "_qd")


def _k():
    return kernel.load_compiled()  # raises KernelUnavailable (a failure) when not built


def test_register_map_constants_match_the_kernels():
    k = _k()
    assert (k.ENCODER_OFFSET, k.DAC_OFFSET, k.LIMIT_SWITCH_OFFSET, k.AMP_STATUS_OFFSET) == (
        vm.ENCODER_OFFSET, vm.DAC_OFFSET, vm.LIMIT_SWITCH_OFFSET, vm.AMP_STATUS_OFFSET)
    assert (k.ENCODER_MODULUS, k.DAC_MIN, k.DAC_MAX) == (vm.ENCODER_MODULUS, vm.DAC_MIN, vm.DAC_MAX)
    assert (k.AMP_STATUS_POWERED, k.AMP_STATUS_WATCHDOG_FAULT) == (vm.AMP_STATUS_POWERED, vm.AMP_STATUS_WATCHDOG_FAULT)


def test_matvec_is_numpys_product_bit_for_bit():
    k, rng = _k(), np.random.default_rng(5)
    for m, n in ((24, 36), (24, 6), (7, 3)):
        for _ in range(200):
            a = rng.standard_normal((m, n)) * 10.0 ** rng.uniform(-9, 4, (m, n))
            x = rng.standard_normal(n) * 10.0 ** rng.uniform(-9, 4, n)
            y = np.empty(m)
            k.matvec(a, x, y)
            assert y.tobytes() == (a @ x).tobytes()


# -- the plant's exact step, one advance from random states -------------------------------------
_PLANTS: dict = {}


def _plants():
    if not _PLANTS:
        for name in ("python", "c"):
            _PLANTS[name] = ReisPlant(ReisPlantParams(), seed=3, kernel=name)
    return _PLANTS["python"], _PLANTS["c"]


def _speed():
    # at rest (stiction), creeping (reversal within a step), moving (kinetic friction)
    return st.one_of(st.just(0.0), st.floats(-1e-3, 1e-3), st.floats(-40.0, 40.0))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(q_deg=st.lists(st.floats(-60.0, 60.0), min_size=6, max_size=6),
       defl=st.lists(st.floats(-2e-3, 2e-3), min_size=6, max_size=6),
       omega=st.lists(_speed(), min_size=6, max_size=6),
       qd=st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6),
       dacs=st.lists(st.integers(-2048, 2047), min_size=6, max_size=6),
       amps=st.booleans(), ext=st.one_of(st.none(), st.lists(st.floats(-50.0, 50.0), min_size=6, max_size=6)),
       steps=st.integers(1, 3))
def test_exact_step_is_the_references_bit_for_bit(q_deg, defl, omega, qd, dacs, amps, ext, steps):
    """Random states (links anywhere within +-60 deg, drive deflections, motors at rest, creeping
    or moving), random DAC words, amplifiers on or off, with or without a contact torque: the
    registers and the state after each advance are the same bytes."""
    plants = _plants()
    q = np.radians(np.asarray(q_deg))
    for p in plants:
        p._q = q.copy()
        p._qd = np.asarray(qd, float)
        p._theta = p._Ainv @ (q + np.asarray(defl))
        p._omega = np.asarray(omega, float)
        p._lin_q = None  # relinearise at this pose
        p._amps_on, p._wd_fault = amps, not amps
        p._wd_age_s = [0.0, 0.0]
        p._q_list = (None, None)
        vm.store(p._view, vm.DAC_OFFSET, vm.DACS_FORMAT, *dacs)
    for _ in range(steps):
        for p in plants:
            p.contact = None if ext is None else _Push(ext)
            p.advance(0.002)
        a, b = plants
        assert bytes(a.regs) == bytes(b.regs)
        for k in STATE:
            assert getattr(a, k).tobytes() == getattr(b, k).tobytes(), k
        assert a._enc_written == b._enc_written


class _Push:
    """A contact that pushes with fixed joint torques [N m]."""

    def __init__(self, tau):
        self.tau = np.asarray(tau, float)

    def joint_torque(self, body, q, qd, dt_s):
        return self.tau


def test_the_compiled_step_is_the_one_that_runs():
    """With kernel="c" the advance goes through droid._kernel.exact_step (a counting proxy)."""
    p = ReisPlant(ReisPlantParams(), seed=1, kernel="c")
    calls = []

    class Spy:
        def __getattr__(self, name):
            fn = getattr(p_k, name)
            return lambda *a: (calls.append(name), fn(*a))[1]
    p_k = p._k
    p._k = Spy()
    for _ in range(5):
        p.advance(0.002)
    assert calls.count("exact_step") == 5
    assert ReisPlant(ReisPlantParams(), seed=1, kernel="python")._k is None


def _cells(rigid=False):
    params = ReisPlantParams(compliance=False) if rigid else ReisPlantParams()
    return {k: ReisLockstep(ReisPlant(params, seed=1, kernel=k), ServoCore(None, kernel=k)) for k in ("python", "c")}


def _same(cells) -> bool:
    return plants_same_bits(cells["python"].plant, cells["c"].plant)


@pytest.mark.parametrize("rigid", [False, True], ids=["compliant-exact", "rigid"])
def test_a_servo_and_plant_pair_stays_bit_identical_through_homing_and_a_move(rigid):
    """Two cells, the reference and the kernel (plant and PID), side by side: homing from power-up,
    then a 2 s move of all six joints out and back -- the same bits after every 0.5 s."""
    cells = _cells(rigid)

    def check() -> None:
        assert _same(cells)
    drive_side_by_side(cells, [60.0, 45.0, -50.0, 90.0, 70.0, 120.0], 1, check)
    assert all(c.servo.homed for c in cells.values())
    assert cells["c"].servo.dac == cells["python"].servo.dac


# -- the PID --------------------------------------------------------------------------------------
_gain = st.floats(0.0, 50.0)


@settings(max_examples=200, deadline=None)
@given(kp=st.lists(_gain, min_size=6, max_size=6), ki=st.lists(st.floats(0.0, 2.0), min_size=6, max_size=6),
       kd=st.lists(_gain, min_size=6, max_size=6), lim=st.lists(st.floats(0.0, 3000.0), min_size=6, max_size=6),
       errors=st.lists(st.lists(st.integers(-5000, 5000), min_size=6, max_size=6), min_size=1, max_size=30),
       reset_at=st.integers(0, 30))
def test_pid_is_the_references_bit_for_bit(kp, ki, kd, lim, errors, reset_at):
    """Random gains and error sequences (saturating and not, a reset in between): the same
    outputs, rounded outputs and integrals, bit for bit."""
    pids = [Pid(kp, ki, kd, lim, -2048, 2047, kernel=k) for k in ("python", "c")]
    rounded = [Pid(kp, ki, kd, lim, -2048, 2047, kernel=k) for k in ("python", "c")]
    for i, e in enumerate(errors):
        if i == reset_at:
            for p in pids + rounded:
                p.reset()
        a, b = (p.step(e) for p in pids)
        assert type(a) is type(b) is list
        assert np.array(a).tobytes() == np.array(b).tobytes()
        assert pids[0].integral.tobytes() == pids[1].integral.tobytes()
        ra, rb = (p.step_rounded(e) for p in rounded)
        assert ra == rb and all(type(x) is int for x in rb)


def test_pid_rounds_half_to_even_as_round_does():
    pid = Pid([0.5] * 6, [0.0] * 6, [0.0] * 6, [0.0] * 6, -2048, 2047, kernel="c")
    assert pid.step_rounded([1, 3, 5, -1, -3, 0]) == (0, 2, 2, 0, -2, 0)  # 0.5, 1.5, 2.5, ...


# -- the switch ----------------------------------------------------------------------------------
def _probe(env_value: str) -> subprocess.CompletedProcess:
    code = ("from droid import kernel; from droid.sim.reis.plant import ReisPlant; "
            "from droid.subunits.reis.servo import ServoCore; import droid._kernel as k; "
            "p = ReisPlant(); s = ServoCore(); "
            "print(kernel.NAME, p._k is k, s._pid._k is k, p._k is None and s._pid._k is None)")
    env = dict(os.environ, DROID_KERNEL=env_value, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)


def test_droid_kernel_c_puts_the_compiled_module_in_use():
    r = _probe("c")
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["c", "True", "True", "False"]


def test_droid_kernel_python_uses_the_reference():
    r = _probe("python")
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["python", "False", "False", "True"]


def test_the_default_uses_the_compiled_kernel_when_it_is_built():
    """``auto`` (DROID_KERNEL unset or empty): the compiled kernel wherever the install built it
    -- this checkout's is (scripts/venv.sh) -- so real time and lockstep run the same code."""
    r = _probe("")
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["c", "True", "True", "False"]


def test_auto_falls_back_to_the_reference_and_says_why_while_c_refuses(tmp_path):
    """A checkout without the built extension: ``auto`` runs the reference (the same bits) and
    ``describe()`` says why; an explicit ``c`` stops at import instead."""
    shadow = tmp_path / "droid"
    shadow.mkdir()
    (shadow / "_kernel.py").write_text("raise ImportError('not built here')\n")
    code = ("import sys; import droid; droid.__path__.insert(0, sys.argv[1]); "
            "from droid import kernel; print(kernel.NAME); print(kernel.describe())")
    for value, ok in (("auto", True), ("c", False)):
        env = dict(os.environ, DROID_KERNEL=value, PYTHONPATH=str(ROOT))
        r = subprocess.run([sys.executable, "-c", code, str(shadow)], env=env, capture_output=True, text=True,
                           timeout=300)
        if ok:
            assert r.returncode == 0, r.stderr
            name, line = r.stdout.splitlines()
            assert name == "python" and "not usable" in line and "not built here" in line
        else:
            assert r.returncode != 0 and "KernelUnavailable" in r.stderr and "not built here" in r.stderr


def test_an_unknown_kernel_is_refused():
    r = _probe("fortran")
    assert r.returncode != 0 and "KernelUnavailable" in r.stderr and "fortran" in r.stderr


# -- the servo tick's integer parts ------------------------------------------------------------------
@settings(max_examples=200, deadline=None)
@given(start=st.lists(st.integers(-10**9, 10**9), min_size=6, max_size=6),
       moves=st.lists(st.lists(st.integers(-40000, 40000), min_size=6, max_size=6), min_size=1, max_size=20),
       periods=st.integers(1, 3))
def test_counter_extension_is_the_references(start, moves, periods):
    """Unbounded counts from 16-bit counters (roll-over both ways, jumps past the limit): the
    same positions and the same ENCODER_JUMP verdicts."""
    cores = [ServoCore(None, kernel=k) for k in ("python", "c")]
    true = np.array(start, np.int64)
    for c in cores:
        c._read_encoders([int(x) % 65536 for x in true])
    for m in moves:
        true = true + np.array(m, np.int64)
        raw = tuple(int(x) % 65536 for x in true)
        for c in cores:
            c._read_encoders(raw, periods)
        a, b = cores
        assert a._pos.dtype == b._pos.dtype == np.int64
        assert a._pos.tolist() == b._pos.tolist() and a._fault == b._fault


@settings(max_examples=200, deadline=None)
@given(values=st.lists(st.integers(-10**20, 10**20) | st.integers(-3000, 3000), min_size=6, max_size=6))
def test_dac_write_is_the_drivers(values):
    """Six ints clamped to -2048..2047 and stored: the same register bytes and the same answer
    as VmeBus.write_dacs's Python path."""
    from droid.subunits.reis import vme
    k = _k()
    regs_py, regs_c = bytearray(vm.MAP_SIZE), bytearray(vm.MAP_SIZE)
    saved, vme._K = vme._K, None
    try:
        written = vme.VmeBus(regs_py).write_dacs(tuple(values))
    finally:
        vme._K = saved
    assert k.write_dacs(memoryview(regs_c), tuple(values)) == written
    assert regs_c == regs_py
    assert k.write_dacs(memoryview(regs_c), (1.5, 0, 0, 0, 0, 0)) is None  # floats: the Python path's


@pytest.mark.parametrize("theta", [1e17, -3.3e18, 123456.789, -0.5, float("nan"), float("inf")])
def test_encoder_write_matches_the_reference_for_any_motor_angle(theta):
    """The encoder registers of a far-off (diverged) motor angle: the same value as Python's
    floor and modulo on unbounded ints, the same exception for NaN and infinity."""
    plants = [ReisPlant(ReisPlantParams(compliance=False), seed=2, kernel=k) for k in ("python", "c")]
    outcome = []
    for p in plants:
        p._theta = p._theta.copy()
        p._theta[2] = theta
        try:
            p._write_outputs()
            outcome.append(bytes(p.regs))
        except (ValueError, OverflowError) as e:
            outcome.append(type(e))
    assert outcome[0] == outcome[1]


@settings(max_examples=150, deadline=None)
@given(walk=st.lists(st.lists(st.integers(-900, 900), min_size=6, max_size=6), min_size=2, max_size=40),
       jogs=st.lists(st.tuples(st.integers(0, 39), st.lists(st.integers(-5000, 5000), min_size=6, max_size=6)),
                     max_size=6),
       home_at=st.one_of(st.none(), st.integers(0, 39)))
def test_servo_tick_is_the_references(walk, jogs, home_at):
    """Whole servo ticks (ServoCore.step: counters, target, clip, velocity, following-error check,
    PID, round) on random encoder walks with JOG commands and HOME (a switch never found fails
    it): the same DACs, faults, targets and velocities, tick for tick."""
    cores = [ServoCore(None, kernel=k) for k in ("python", "c")]
    counts = np.array([1000, 20000, 40000, 60000, 300, 30000], np.int64)
    sw = (False,) * 6
    jog_at = dict(jogs)
    for i, step in enumerate(walk):
        counts = counts + np.array(step, np.int64)
        raw = tuple(int(x) % 65536 for x in counts)
        if i == home_at:
            for c in cores:
                c.command(Mode.HOME)
        if i in jog_at:
            for c in cores:
                c.command(Mode.JOG, jog_at[i])
        out = [c.step(raw, sw) for c in cores]
        a, b = cores
        assert out[0] == out[1] and all(type(x) is int for x in out[1])
        assert a.fault == b.fault and a._target.tolist() == b._target.tolist() and a._vel.tolist() == b._vel.tolist()
        assert a.integral_dac == b.integral_dac


@pytest.mark.parametrize("err", [3999, 4000, 4001, -4000, -4001, 2**53 + 1, -(2**62)])
def test_following_error_limit_is_compared_as_python_compares_int_and_float(err):
    """The fault verdict at and around the limit (4000.0 counts) and far beyond 2^53."""
    k = _k()
    pid = Pid([1.0] * 6, [0.0] * 6, [0.0] * 6, [0.0] * 6, -2048, 2047, kernel="c")
    target = np.array([err, 0, 0, 0, 0, 0], np.int64)
    fe_max = np.full(6, 4000.0)
    dac = k.servo_tail(target, target.copy(), None, None, np.zeros(6, np.int64), fe_max, np.empty(6, np.int64),
                       pid._gains, pid._state, True)
    assert (dac is None) == any(e > lim or -e > lim for e, lim in zip([err, 0, 0, 0, 0, 0], fe_max.tolist()))


@settings(max_examples=300, deadline=None)
@given(q_deg=st.lists(st.floats(-400.0, 400.0), min_size=6, max_size=6),
       moved_deg=st.one_of(st.none(), st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6)))
def test_exact_step_guards_are_the_references(q_deg, moved_deg):
    """The stop and relinearisation guards of the exact step: the compiled exact_checks answers as
    ReisPlant._near_stop and _discretise's test do (links anywhere, near and past the stops)."""
    p = _plants()[0]
    k = _k()
    q = np.radians(np.asarray(q_deg))
    lin = None if moved_deg is None else q + np.radians(np.asarray(moved_deg))
    p._stop_lim.clear()
    near = p._near_stop(0.002, q.tolist())
    relin = lin is None or any(abs(a - b) > p._relin_rad for a, b in zip(q.tolist(), lin.tolist()))
    want = 2 if near else (1 if relin else 0)
    assert k.exact_checks(q, lin, p._relin_rad, p._stop_mid, np.array(p._stop_lim[0.002])) == want
