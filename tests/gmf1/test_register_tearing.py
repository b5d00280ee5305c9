"""The encoder cards' registers, shared between droid-sim's twin and droid-gmf1-encoder, are never
seen half-written.  A real bug: the twin wrote them with ``struct.pack_into``, which zero-fills
before it writes, so the encoder program now and then read a COUNT of 0 -- joint 1 at home for one
cycle, a 26 deg step that droid-guard took for the holder inside the ABB and stopped the cell on
(CI, 2026-12-03).  The Reis's registers have the same test (tests/reis/test_register_tearing.py)."""
import mmap
import multiprocessing as mp

import numpy as np

from droid.sim.gmf1.cards import Quad04Twin
from droid.subunits.gmf1 import quad04_map as qm
from droid.subunits.gmf1.quad04 import Quad04Bank, Quad04Card

CTX = mp.get_context("fork")
WRITES = 20000


def _writer(twin, go, done):
    go.wait(10)
    a, b = np.full(qm.JOINTS, 100000.0), np.full(qm.JOINTS, 100001.0)
    for k in range(WRITES):  # every update rewrites all six counters, never with a 0 in them
        twin.update(a if k % 2 else b)
    done.set()


def test_encoder_counters_never_read_zero_while_the_twin_writes():
    bufs = [mmap.mmap(-1, qm.MAP_SIZE) for _ in range(qm.CARDS)]  # shared with the forked writer
    twin = Quad04Twin(bufs, np.random.default_rng(1))
    twin.offset = [0] * len(twin.offset)  # counting from 0 at home: a torn 0 would read as home
    twin.update(np.full(qm.JOINTS, 100001.0))  # non-zero counters before the reader starts
    go, done = CTX.Event(), CTX.Event()
    p = CTX.Process(target=_writer, args=(twin, go, done))
    p.start()
    bank = Quad04Bank([Quad04Card(memoryview(b)) for b in bufs])
    reads = zeros = 0
    try:
        go.set()
        while not done.is_set():
            raw, _ = Quad04Bank.joints_from(bank.channel_bytes())
            reads += 1
            zeros += int(np.count_nonzero(raw == 0))
    finally:
        p.join(30)
        bank.close()
        twin.release()
    assert p.exitcode == 0
    assert reads > 0
    assert zeros == 0, f"{zeros} zero counters in {reads} reads of the cards"
