"""The Reis plant's rigid-drive substeps compiled (droid/_kernel.c ``rigid_steps``) against the
Python reference (``ReisPlant._steps_rigid``), bit for bit.

droid-sim's world runs the plant on rigid drives (``compliance = false``, the cell's default) with
the compiled rigid body, and the rigid lockstep cells (droid.sim.reis.lockstep.homed_rigid_cell,
the servo-logic tests) with Pinocchio's; the compiled substeps serve both.  The tolerance is zero:
the kernel performs the reference's IEEE operations in its order, every ``@`` through numpy's own
dgemv and the solve through numpy's own LAPACK dgesv (droid.kernel), and leaves an advance to the
reference where it cannot promise the same bits (near a hard stop, a jammed motor, a value not
finite, a floating-point exception numpy would warn of).  Two plants, one per backend, are driven
with the same random DAC words, contact torques, watchdog kicks and lapses, power cycles and jams
and compared after every advance: the register map, the time and the state, byte for byte.  The
kernel is built by ``pip install -e .`` (setup.py); these tests fail, not skip, without it.
"""
from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from droid import kernel
from droid.sim.reis.lockstep import plants_same_bits
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.subunits.reis import vme_map as vm

RIGID = ReisPlantParams(compliance=False)
STATE = ("_theta", "_omega", "_q", "_qd")


class _Spy:
    """The plant's compiled module with ``rigid_steps`` counted: calls taken, calls left to Python
    (with ``plant``: each of those must be an advance near a hard stop, ``_near_stop``'s test)."""

    def __init__(self, k, plant=None) -> None:
        self.k, self.plant, self.taken, self.left = k, plant, 0, 0

    def __getattr__(self, name):
        return getattr(self.k, name)

    def rigid_steps(self, *args):
        out = self.k.rigid_steps(*args)
        if out is None:
            self.left += 1
            if self.plant is not None:
                q, n, h = args[10], args[12], args[13]
                assert self.plant._near_stop(n * h, q.tolist()), "left to Python away from the stops"
        else:
            self.taken += 1
        return out


class _Contact:
    """A contact whose joint torques the test sets before each advance (None: no contact)."""

    def __init__(self) -> None:
        self.tau = None

    def joint_torque(self, body, q, qd, dt_s):
        return self.tau


def _pair(rigid_body: str, **kw):
    ref = ReisPlant(RIGID, seed=7, kernel="python", rigid_body=rigid_body, **kw)
    c = ReisPlant(RIGID, seed=7, kernel="c", rigid_body=rigid_body, **kw)
    assert ref._k_rigid is None and c._k_rigid is not None
    c._k_rigid = spy = _Spy(c._k_rigid, c)
    for p in (ref, c):
        p.contact = _Contact()
    return ref, c, spy


def _same(a, b) -> None:
    assert bytes(a.regs) == bytes(b.regs)
    assert a.time_s == b.time_s
    for k in STATE:
        assert getattr(a, k).tobytes() == getattr(b, k).tobytes(), k
    assert a._enc_written == b._enc_written
    assert (a.amps_on, a._wd_fault, a.rest_steps) == (b.amps_on, b._wd_fault, b.rest_steps)


def _drive(ref, c, rng, advances: int, dt: float, *, dac_scale: int = 2047, jam: bool = True,
           lapse: bool = True) -> dict:
    """Both plants, the same inputs, compared after every advance: DAC words held for a random
    number of advances (at rest with zero words too), the two watchdog registers kicked (amplifiers
    on) or left alone past the timeout (latched off, then a power cycle), contact torques on a
    third of the advances, a motor jammed for a while.  Returns how many advances saw each case."""
    dacs, hold, kick, kicks_off_until, jam_until, jammed = (0,) * 6, 0, 0, -1, -1, None
    seen = dict.fromkeys(("amps_on", "amps_off", "contact", "jammed", "at_stop", "power_cycles"), 0)
    for i in range(advances):
        if hold == 0:
            hold = int(rng.integers(1, 60))
            r = rng.random()
            dacs = ((0,) * 6 if r < 0.15 else
                    tuple(int(x) for x in rng.integers(-dac_scale, dac_scale + 1, 6)) if r < 0.8 else
                    tuple(int(x) for x in rng.integers(-40, 41, 6)))  # small words: stiction, creeping
        hold -= 1
        if lapse and kicks_off_until < i and rng.random() < 0.003:
            kicks_off_until = i + int(math.ceil(0.15 / dt))  # past the 100 ms timeout: latched off
        if i == kicks_off_until:
            for p in (ref, c):
                p.power_cycle()
            seen["power_cycles"] += 1
        if i >= kicks_off_until:
            kick = (kick + 1) % 65536
        if jam and jammed is None and rng.random() < 0.002:
            jammed, jam_until = int(rng.integers(0, 6)), i + int(rng.integers(5, 80))
            for p in (ref, c):
                p.jam(jammed)
        if jammed is not None and i >= jam_until:
            for p in (ref, c):
                p.jam(jammed, False)
            jammed = None
        tau = rng.standard_normal(6) * 10.0 ** rng.uniform(-2, 1.5, 6) if rng.random() < 0.3 else None
        for p in (ref, c):
            vm.store(p._view, vm.DAC_OFFSET, vm.DACS_FORMAT, *dacs)
            if i >= kicks_off_until:
                struct.pack_into("<2H", p._view, vm.WATCHDOG_OFFSETS[0], kick, kick)
            p.contact.tau = None if tau is None else tau.copy()
            p.advance(dt)
        _same(ref, c)
        seen["amps_on" if ref.amps_on else "amps_off"] += 1
        seen["contact"] += tau is not None
        seen["jammed"] += jammed is not None
        seen["at_stop"] += bool(np.any((ref._q >= ref._stop_max) | (ref._q <= ref._stop_min)))
    return seen


@pytest.mark.parametrize("dt", [0.0005, 0.001, 0.002], ids=["1-substep", "world-1ms", "lockstep-2ms"])
@pytest.mark.parametrize("rigid_body", ["kernel", "pinocchio"])
def test_rigid_substeps_are_the_references_bit_for_bit(rigid_body, dt):
    """Random DAC words, contact torques, watchdog lapses, power cycles and jams over 2500 advances
    from the seeded power-up pose: the same bits after every advance, the compiled call taking
    every advance where no motor is jammed and no link near a stop (at 2 ms the arm sinks to
    joint 2's stop within the 5 s: those advances are the reference's)."""
    ref, c, spy = _pair(rigid_body)
    seen = _drive(ref, c, np.random.default_rng(int(dt * 1e5) + len(rigid_body)), 2500, dt)
    assert spy.taken > 800, (spy.taken, spy.left, seen)
    assert all(seen[k] > 0 for k in ("amps_on", "amps_off", "contact", "jammed", "power_cycles")), seen


@pytest.mark.parametrize("rigid_body", ["kernel", "pinocchio"])
def test_moves_into_the_hard_stops_are_the_references(rigid_body):
    """Powered up 2.5 deg inside each joint's hard stop (alternately the upper and the lower) and
    driven with full-scale words: the advances near a stop go to the reference (``_apply_stops``),
    the others to the kernel, the bits never part -- links at the stops included."""
    lo, hi = np.asarray(RIGID.hard_stop_min_deg), np.asarray(RIGID.hard_stop_max_deg)
    pose = np.where(np.arange(6) % 2 == 0, hi - 2.5, lo + 2.5)
    ref, c, spy = _pair(rigid_body, initial_joint_deg=pose)
    seen = _drive(ref, c, np.random.default_rng(11), 3000, 0.001, jam=False, lapse=False)
    assert spy.taken > 100 and spy.left > 100, (spy.taken, spy.left, seen)  # both sides of _near_stop
    assert seen["at_stop"] > 0, seen  # a link at its stop


def test_random_states_one_advance_each():
    """Random states set on both plants (motors at rest, creeping at the friction's edge, moving
    fast; links anywhere inside the stops), one advance of random words and contact each: the same
    bits, the kernel taking nearly all of them."""
    ref, c, spy = _pair("kernel")
    rng = np.random.default_rng(5)
    for i in range(1500):
        theta = ref._Ainv @ np.radians(rng.uniform(-60.0, 60.0, 6))
        kind = rng.integers(0, 3, 6)
        omega = np.where(kind == 0, 0.0, np.where(kind == 1, rng.uniform(-3e-3, 3e-3, 6), rng.uniform(-60, 60, 6)))
        dacs = tuple(int(x) for x in rng.integers(-2048, 2048, 6))
        tau = rng.standard_normal(6) * 20.0 if i % 3 == 0 else None
        for p in (ref, c):
            p._theta, p._omega = theta.copy(), omega.copy()
            p._q, p._qd = p._A @ p._theta, p._A @ p._omega
            p._rest = None
            vm.store(p._view, vm.DAC_OFFSET, vm.DACS_FORMAT, *dacs)
            struct.pack_into("<2H", p._view, vm.WATCHDOG_OFFSETS[0], i % 65536, i % 65536)
            p.contact.tau = tau
            p.advance(0.001)
        _same(ref, c)
    assert spy.taken > 1400


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_state_not_finite_is_left_to_the_reference(bad):
    """A speed that is NaN or infinite: the kernel declines the advance and the reference takes it
    (its np.where stops a NaN motor; an infinite one ends in the encoders' OverflowError or
    ValueError) -- the same bits, or the same error, either way."""
    out = []
    for name in ("python", "c"):
        p = ReisPlant(RIGID, seed=2, kernel=name, rigid_body="kernel")
        if name == "c":
            p._k_rigid = spy = _Spy(p._k_rigid)
        struct.pack_into("<2H", p._view, vm.WATCHDOG_OFFSETS[0], 1, 1)
        p._omega = np.array([0.0, bad, 0.0, 0.0, 0.0, 0.0])
        with np.errstate(all="ignore"):
            try:
                p.advance(0.001)
                out.append((bytes(p.regs), [getattr(p, k).tobytes() for k in STATE]))
            except (ValueError, OverflowError) as e:
                out.append((type(e), str(e)))
    assert out[0] == out[1]
    assert spy.left == 1 and spy.taken == 0


def test_the_compiled_substeps_run_only_where_they_should():
    """Rigid drives with the compiled kernel: rigid_steps; the compliant arm (the exact step and its
    substep fallback), DROID_KERNEL=python's plants, and an extension built before rigid_steps: not."""
    k = kernel.load_compiled()
    assert kernel.rigid_ready(k) and kernel.GESV
    assert ReisPlant(RIGID, seed=1, kernel="c")._k_rigid is k
    assert ReisPlant(ReisPlantParams(), seed=1, kernel="c")._k_rigid is None
    assert ReisPlant(RIGID, seed=1, kernel="python")._k_rigid is None

    class Old:  # an extension without rigid_steps
        pass
    assert not kernel.rigid_ready(Old()) and not kernel.rigid_ready(None)


def test_the_kernels_solve_is_numpys_bit_for_bit():
    """droid._kernel.solve (numpy's dgesv by its address) against np.linalg.solve and the plant's
    _solve on the rigid plant's own systems, M(q) + the rotors, and on general ones."""
    from droid.sim.reis.plant import _solve

    k, rng = kernel.load_compiled(), np.random.default_rng(9)
    p = ReisPlant(RIGID, seed=1, kernel="c", rigid_body="kernel")
    for i in range(500):
        if i % 2:
            a = p.body.mass(np.radians(rng.uniform(-170, 170, 6))) + p._J_rotor_ref
        else:
            a = rng.standard_normal((6, 6)) * 10.0 ** rng.uniform(-4, 4, (6, 6))
        b = rng.standard_normal(6) * 10.0 ** rng.uniform(-3, 3, 6)
        x = np.empty(6)
        assert k.solve(a, b, x) == 0
        assert x.tobytes() == np.linalg.solve(a, b).tobytes() == _solve(a, b).tobytes()


def test_a_lockstep_rigid_cell_is_unchanged_by_the_kernel():
    """The rigid lockstep plant (Pinocchio's body) under each kernel through 4 s of full-scale
    words at 2 ms advances, as the servo-logic tests run it: the same bits."""
    ref, c, spy = _pair("pinocchio")
    rng = np.random.default_rng(3)
    for i in range(2000):
        if i % 50 == 0:
            dacs = tuple(int(x) for x in rng.integers(-2048, 2048, 6))
        for p in (ref, c):
            vm.store(p._view, vm.DAC_OFFSET, vm.DACS_FORMAT, *dacs)
            struct.pack_into("<2H", p._view, vm.WATCHDOG_OFFSETS[0], i % 65536, i % 65536)
            p.advance(0.002)
        assert plants_same_bits(ref, c)
    assert spy.taken > 1000
