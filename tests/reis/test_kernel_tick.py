"""The servo's and the plant's one-call ticks (issue 44, droid/_kernel.c ``servo_cycle`` and
``exact_step``'s 18-argument form) against the Python reference, bit for bit.

As tests/reis/test_kernel.py: the tolerance is zero.  ``ServoStation.cycle`` on a
:class:`~droid.subunits.reis.vme.VmeBus` takes the whole tick (registers read, counters extended,
way-point, clip, velocity, following-error check, PID, DACs written) in one kernel call on its
common path and hands every other tick (the cache, the coast, the brake, homing, a fault) to the
reference; the plant's exact step asks the kernel for its guards, ``nle`` and the step at once.
Both must leave the same registers, messages and state as the reference, tick for tick.
"""
from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from droid import kernel
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.subunits.reis import servo_wire as sw
from droid.subunits.reis import vme_map as vm
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.servo_params import Mode
from droid.subunits.reis.station import ServoStation
from droid.subunits.reis.vme import VmeBus

STATE = ("_theta", "_omega", "_q", "_qd")


class _Counting:
    """The compiled module, counting the calls of ``name`` (and the argument counts)."""

    def __init__(self, k, name: str):
        self._k, self._name, self.calls = k, name, []

    def __getattr__(self, attr):
        fn = getattr(self._k, attr)
        if attr != self._name:
            return fn
        return lambda *a: (self.calls.append(len(a)), fn(*a))[1]


def _stations():
    out = []
    for name in ("python", "c"):
        regs = bytearray(vm.MAP_SIZE)
        out.append((regs, ServoStation(ServoCore(None, kernel=name), VmeBus.from_buffer(regs))))
    return out


def _servo_state(station: ServoStation) -> tuple:
    c = station.core
    q = c._queue
    return (c.tick, int(c.mode), int(c.fault), c.homed, c._pos.tolist() if c._pos is not None else None,
            c._target.tolist(), c._vel.tolist(), c.dac, c.integral_dac, q._qi, q._queue.tolist(), q.starved,
            q.braking, station.raw, station.dacs, c.refused_resumes)


_step = st.lists(st.integers(-400, 400), min_size=6, max_size=6)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(walk=st.lists(st.tuples(_step, st.integers(0, 3)), min_size=4, max_size=60),
       cmds=st.lists(st.tuples(st.integers(0, 59), st.sampled_from([Mode.JOG, Mode.NORMAL, Mode.HOME, Mode.OFF]),
                               st.lists(st.integers(-3000, 3000), min_size=6, max_size=6)), max_size=12),
       homed=st.booleans(), jump_at=st.one_of(st.none(), st.integers(0, 59)), switches=st.integers(0, 63))
def test_servo_cycle_is_the_references_tick_for_tick(walk, cmds, homed, jump_at, switches):
    """Random encoder walks in the registers (the plant's motion, some ticks standing still, an
    encoder jump), JOG / NORMAL / HOME / OFF command messages at random ticks (starving, coasting,
    braking, a following error on a large jump), homed (the min/max clip) or not: the status
    messages, the DAC registers, what the station read and wrote and the core's and queue's state
    are the same after every tick; and the one-call tick is the one that ran on most of them."""
    (ra, a), (rb, b) = _stations()
    spy = b.core._pid._k = _Counting(b.core._pid._k, "servo_cycle")
    counts = np.array([1000, 20000, 40000, 60000, 300, 30000], np.int64)
    vm.store(ra, vm.LIMIT_SWITCH_OFFSET, vm.U16_FORMAT, switches)
    vm.store(rb, vm.LIMIT_SWITCH_OFFSET, vm.U16_FORMAT, switches)
    at: dict = {}
    for i, mode, counts_cmd in cmds:
        at.setdefault(i, []).append((mode, counts_cmd))
    seq = 0
    for i, (move, repeat) in enumerate(walk):
        counts = counts + (np.array(move, np.int64) if i != jump_at else 5000)
        for regs in (ra, rb):
            vm.store(regs, vm.ENCODER_OFFSET, vm.ENCODERS_FORMAT, *[int(x) % 65536 for x in counts])
        for mode, c in at.get(i, ()):
            seq += 1
            msg = sw.pack_command(sw.ServoCommand(seq, int(mode), tuple(c)))
            assert a.take(msg) == b.take(msg)
        if i == 1 and homed:  # homed: the same zero and limits in both (the clip to the min/max counts)
            for s in (a, b):
                s.core._zero = s.core._pos.copy()
                s.core._limits = (s.core._zero + s.core._tmin, s.core._zero + s.core._tmax)
        for _ in range(1 + repeat):  # ticks standing still: the queue runs on, the brake, the hold
            assert a.cycle() == b.cycle()
            assert bytes(ra) == bytes(rb)
            assert _servo_state(a) == _servo_state(b)
    ticks = sum(1 + r for _, r in walk)
    assert len(spy.calls) <= ticks
    assert a.core.tick == b.core.tick


def test_the_servos_one_call_tick_runs_on_a_steady_stream():
    """On a JOG stream every station tick is the kernel's servo_cycle -- the cache loads too (one
    tick in 8 or 9: CommandQueue._load_cache run first, then the kernel takes the ramp's head) --
    but two: the first (no counts read yet, so the first message is ignored) and the ninth (the
    hold's braking queue refilled before the second message), the same bits throughout."""
    (ra, a), (rb, b) = _stations()
    spy = b.core._pid._k = _Counting(b.core._pid._k, "servo_cycle")
    counts = np.array([1000, 20000, 40000, 60000, 300, 30000], np.int64)
    ticks = 0
    for period in range(60):
        msg = sw.pack_command(sw.ServoCommand(period, int(Mode.JOG), (40, -30, 20, 10, -5, 3)))
        a.take(msg), b.take(msg)
        for _ in range(8 + (period % 3 == 0)):
            counts = counts + np.array([4, -3, 2, 1, 0, 0])
            for regs in (ra, rb):
                vm.store(regs, vm.ENCODER_OFFSET, vm.ENCODERS_FORMAT, *[int(x) % 65536 for x in counts])
            assert a.cycle() == b.cycle()
            assert bytes(ra) == bytes(rb) and _servo_state(a) == _servo_state(b)
            ticks += 1
    assert len(spy.calls) == ticks - 2


def test_a_bus_of_another_type_keeps_the_reference_cycle():
    """The one-call tick reads the map's bytes: a driver that is not a VmeBus is driven through its
    methods, as before."""

    class OtherBus:
        amps_powered = True

        def __init__(self):
            self.dacs = []

        def read_encoders_raw(self):
            return (0,) * 6

        def read_limit_switches(self):
            return (False,) * 6

        def write_dacs(self, dacs):
            self.dacs.append(dacs)
    bus = OtherBus()
    station = ServoStation(ServoCore(None, kernel="c"), bus)
    for _ in range(9):
        station.cycle()
    assert station._regs is None and len(bus.dacs) == 9


# -- the plant: the guards, nle and the exact step in one call ------------------------------------
_PLANTS: dict = {}


def _plants():
    if not _PLANTS:
        for name in ("python", "c"):
            _PLANTS[name] = ReisPlant(ReisPlantParams(), seed=3, kernel=name)
    return _PLANTS["python"], _PLANTS["c"]


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(q_deg=st.lists(st.floats(-60.0, 60.0), min_size=6, max_size=6),
       omega=st.lists(st.one_of(st.just(0.0), st.floats(-1e-3, 1e-3), st.floats(-40.0, 40.0)), min_size=6, max_size=6),
       dacs=st.lists(st.lists(st.integers(-2048, 2047), min_size=6, max_size=6), min_size=2, max_size=8),
       amps=st.booleans(), far=st.booleans())
def test_the_one_call_exact_step_is_the_references(q_deg, omega, dacs, amps, far):
    """A linearisation made, then a run of advances with new DAC words each (motors at rest,
    creeping or moving; the amplifiers on or off): the kernel's one call (guards, nle, step) leaves
    the registers and the state the reference leaves, and hands back the advance where the guards
    say so (``far``: the linearisation moved past its bound, so the reference relinearises)."""
    plants = _plants()
    q = np.radians(np.asarray(q_deg))
    for p in plants:
        p._q, p._qd = q.copy(), np.zeros(6)
        p._theta = p._Ainv @ q
        p._omega = np.asarray(omega, float)
        p._lin_q = None
        p._amps_on, p._wd_fault = amps, not amps
        p._wd_age_s = [0.0, 0.0]
        p._q_list = (None, None)
        p.contact = None
    spy = plants[1]._k = _Counting(plants[1]._k, "exact_step")
    for i, d in enumerate(dacs):
        for p in plants:
            vm.store(p._view, vm.DAC_OFFSET, vm.DACS_FORMAT, *d)
            if far and i == len(dacs) // 2:
                p._lin_q = p._lin_q + 2.0 * p._relin_rad  # (the reference tests _lin_list, the kernel _lin_q)
                p._lin_list = p._lin_q.tolist()
            p._wd_age_s = [0.0, 0.0]
            p.advance(0.002)
        a, b = plants
        assert bytes(a.regs) == bytes(b.regs)
        for k in STATE:
            assert getattr(a, k).tobytes() == getattr(b, k).tobytes(), k
        assert a._enc_written == b._enc_written and a._lin_q.tobytes() == b._lin_q.tobytes()
    plants[1]._k = spy._k
    assert 18 in spy.calls  # the one-call form ran (the first advance linearises: the 14-argument form)


def test_the_one_call_exact_step_hands_back_near_a_stop_with_nothing_changed():
    """Guards that fail: 2 (near a hard stop) or 1 (no linearisation) comes back, and neither the
    registers, the state nor nle's buffer was touched."""
    k = kernel.load_compiled()
    p = ReisPlant(ReisPlantParams(), seed=1, kernel="c")
    p.advance(0.002)
    disc = p._disc[0.002]
    lim = p._stop_lim_arr[0.002]
    called = []
    before = (bytes(p.regs), [getattr(p, s).tobytes() for s in STATE])
    x = np.full(24, np.nan)
    for lin, stop_lim, want in ((None, lim, 1), (p._lin_q, np.zeros(6), 2)):
        got = k.exact_step(p._view, p._consts, disc[0], disc[1], p._theta, p._omega, p._q, p._qd,
                           lambda q, qd: called.append(1), None, True, False, p._enc_offset, x, lin, p._relin_rad,
                           p._stop_mid, stop_lim)
        assert got == want
    assert not called and np.isnan(x).all()
    assert (bytes(p.regs), [getattr(p, s).tobytes() for s in STATE]) == before


@settings(max_examples=200, deadline=None)
@given(pos=st.lists(st.integers(-(2**40), 2**40), min_size=6, max_size=6),
       target=st.lists(st.integers(-(2**40), 2**40), min_size=6, max_size=6),
       zero=st.one_of(st.none(), st.lists(st.integers(-(2**33), 2**33), min_size=6, max_size=6)),
       dac=st.lists(st.integers(-2048, 2047), min_size=6, max_size=6), tick=st.integers(0, 2**40),
       mode=st.sampled_from(list(Mode)), amps=st.booleans())
def test_the_compiled_status_message_is_pack_status(pos, target, zero, dac, tick, mode, amps):
    """The servo's status message from the kernel (ServoCore.status_message) is the bytes of
    servo_wire.pack_status(core.status()): home-relative once homed, counts beyond int32 clipped."""
    core = ServoCore(None, kernel="c")
    core._pos, core._target = np.array(pos, np.int64), np.array(target, np.int64)
    core._zero = None if zero is None else np.array(zero, np.int64)
    core._dac, core._tick, core._mode = tuple(dac), tick, mode
    assert core.status_message(amps) == sw.pack_status(core.status(), amps)
