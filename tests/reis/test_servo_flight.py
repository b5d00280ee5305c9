"""droid-servo's flight record: a new fault prints the ticks that led to it (droid.subunits.reis.servo_prog).

The loop runs here on the real ServoCore and VmeBus over a register map in memory, with a
timer, sockets and presence that only count: an encoder register is set 2x the jump limit
away at tick 40, the core takes ENCODER_JUMP, and the log must hold the fault's line, then the
flight record -- a header, one line per tick oldest first, the fault's tick last, with the
jumped position and the positions and targets of the ticks before it.
"""
from __future__ import annotations

import zmq

from droid.brain.runtime.program import Stop
from droid.subunits.reis import servo_prog, vme_map as vm
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.servo_params import Fault, ServoParams
from droid.subunits.reis.vme import VmeBus


class _Timer:
    def __init__(self, regs: bytearray, jump_at: int, counts: int) -> None:
        self.cycles = self.overruns = self.lateness_max_ns = 0
        self.lateness_ns = 0
        self.regs, self.jump_at, self.counts = regs, jump_at, counts

    def wait(self, timeout_s: float) -> int:
        self.cycles += 1
        self.lateness_ns = 1000 * self.cycles  # [ns]: 1 us more each tick, to read back
        if self.cycles == self.jump_at:  # joint 3's counter jumps between two ticks
            vm.store(memoryview(self.regs), vm.ENCODER_OFFSET + 2 * 2, vm.U16_FORMAT, self.counts)
        if self.cycles > self.jump_at + 5:
            Stop.requested = True
        return 1


class _Quiet:
    def recv(self, flags=0):
        raise zmq.Again()

    def send(self, msg, flags=0):
        pass

    def beat(self, *args, **kwargs):
        pass


def _run_to_a_jump(jump_at: int) -> tuple[ServoCore, int]:
    """The servo loop over a register map at 1000 counts, joint 3's counter set 2x the jump limit
    away at tick ``jump_at``; returns the core and the jumped count."""
    p = ServoParams()
    regs = bytearray(vm.MAP_SIZE)
    vm.store(memoryview(regs), vm.ENCODER_OFFSET, vm.ENCODERS_FORMAT, *([1000] * 6))
    jumped = 1000 + 2 * p.max_encoder_step_counts
    core = ServoCore(p)
    loop = servo_prog._ServoLoop("arm1", core, VmeBus(regs), _Timer(regs, jump_at, jumped), _Quiet(), _Quiet(),
                                 _Quiet())
    Stop.requested = False
    try:
        loop.run()
    finally:
        Stop.requested = False
    return core, jumped


def test_a_fault_prints_the_flight_record_of_the_ticks_before_it(capsys):
    core, jumped = _run_to_a_jump(40)
    assert core.fault == Fault.ENCODER_JUMP
    err = capsys.readouterr().err.splitlines()
    fault = [i for i, line in enumerate(err) if "fault ENCODER_JUMP at servo tick" in line]
    assert len(fault) == 1, err
    flight = [line.split(": flight ", 1)[1] for line in err[fault[0] + 1:] if ": flight " in line]
    assert flight[0].split() == list(servo_prog.FLIGHT_COLUMNS)
    rows = [[int(x) for x in line.split()] for line in flight[1:]]
    assert len(rows) == 40  # every tick so far (fewer than FLIGHT_TICKS), oldest first
    col = {name: i for i, name in enumerate(servo_prog.FLIGHT_COLUMNS)}
    assert [r[col["tick"]] for r in rows] == list(range(1, 41))
    assert [r[col["late_us"]] for r in rows] == list(range(1, 41))
    assert all(r[col["periods"]] == 1 for r in rows)
    assert rows[-1][col["pos3"]] == jumped  # the fault's tick: the jumped counter, read
    assert all(r[col["pos3"]] == 1000 and r[col["target3"]] == 1000 for r in rows[:-1])
    assert all(r[col["dac1"]] == 0 for r in rows)  # OFF: nothing driven


def test_the_flight_record_keeps_only_its_last_ticks(capsys):
    n = servo_prog.FLIGHT_TICKS + 57
    _run_to_a_jump(n)
    err = capsys.readouterr().err.splitlines()
    rows = [line.split(": flight ", 1)[1].split() for line in err if ": flight " in line][1:]
    assert [int(r[0]) for r in rows] == list(range(n - servo_prog.FLIGHT_TICKS + 1, n + 1))
