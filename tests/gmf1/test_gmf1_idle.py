"""The GMF1's rest paths (issue 44), each against the full path, tick for tick.  Lockstep only.

* The Fanuc twin's idle advance: with no line, no reply, no motion and the arm at rest on its
  reference, KarelController.advance only moves the clocks.
* droid-gmf1-encoder's rest cycle: the same card registers and homing fields as the last cycle,
  whose step can repeat, give EncoderCore.repeat (the step's own rest path) without the reading.
"""
from __future__ import annotations

import numpy as np

from droid.kinematics.transforms import pose_to_T
from droid.sim.gmf1.controller import KarelParams
from droid.sim.gmf1.lockstep import Gmf1Lockstep
from droid.subunits.gmf1.quad04 import Quad04Bank

TARGET = [1060.51, -165.66, 2295.23, -170.0, 30.0, -160.0]  # global frame, reachable (test_gmf1_lockstep)


def _state(g: Gmf1Lockstep) -> tuple:
    c = g.controller
    return (g.ctrl_status.raw_bytes(), bytes(g.card_bufs[0]), bytes(g.card_bufs[1]), c.q_deg.tobytes(),
            c.q_motor_deg.tobytes(), c.t_s, c.arm.t_s, g.device.bytes_in, g.device.bytes_out, c.completed)


class _OwnBank(Quad04Bank):
    """The same cards through a driver of another type: the encoder station reads them every cycle."""


def test_the_rest_paths_are_the_full_paths():
    """Two dynamic GMF1s, one kept on the full paths: homing, a move, and seconds of holding
    still -- the same Status, cards and twin after every tick; both rest paths ran."""
    ref, fast = (Gmf1Lockstep(params=KarelParams(dynamics=True)) for _ in range(2))
    ref.controller.arm.resting_on = lambda q: False  # never idle: the steps of the full advance
    ref.bank.__class__ = _OwnBank  # never the encoder's rest cycle
    idle, repeats = [], []
    real = fast.controller.arm.resting_on
    fast.controller.arm.resting_on = lambda q: idle.append(real(q)) or idle[-1]
    repeat = fast.encoder_core.repeat
    fast.encoder_core.repeat = lambda: repeats.append(1) or repeat()

    def both(fn) -> None:
        for g in (ref, fast):
            fn(g)
        assert _state(ref) == _state(fast)
    both(lambda g: g.run_ticks(2))
    for g in (ref, fast):
        g.home()
    assert _state(ref) == _state(fast)
    ids = [g.command_cart(pose_to_T(*TARGET), g.ticks_for(2.0)) for g in (ref, fast)]
    for _ in range(400):  # the move, DONE, then holding still
        both(lambda g: g.run_ticks(1))
    assert all(g.done(i) for g, i in zip((ref, fast), ids))
    assert sum(idle) > 1000 and len(repeats) > 200
    assert np.array_equal(ref.controller.q_deg, fast.controller.q_deg)
    assert ref.encoder_core.cycle == fast.encoder_core.cycle and ref.encoder.refreshes == fast.encoder.refreshes
