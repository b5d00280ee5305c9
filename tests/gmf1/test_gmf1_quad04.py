"""The encoder card register map and its driver: round trips over memory, a file (mem://) and shm://."""
import os

import numpy as np
import posix_ipc
import pytest

from droid.cli import BadInput
from droid.sim.gmf1.cards import Quad04Twin, SharedCard
from droid.subunits.gmf1 import quad04_map as qm
from droid.subunits.gmf1.quad04 import (CardUnavailable, Quad04Bank, Quad04Card, check_url, open_bank,
                                        open_card)


def make(seed=0):
    bufs = [bytearray(qm.MAP_SIZE), bytearray(qm.MAP_SIZE)]
    twin = Quad04Twin(bufs, np.random.default_rng(seed))
    bank = Quad04Bank([Quad04Card(b, f"card{i}") for i, b in enumerate(bufs)])
    return bufs, twin, bank


def test_counts_round_trip_with_power_up_offsets_and_wrap():
    bufs, twin, bank = make(3)
    motor = np.array([0, 1000, -5000, 123456, -(1 << 23) - 7, 42])
    twin.update(motor)
    raw, done = bank.read_joints()
    expect = (motor + np.array(twin.offset[:6])) & qm.COUNTER_MASK
    np.testing.assert_array_equal(raw, expect)
    assert np.all(raw < (1 << 24)) and np.all(done == 0)
    # the power-up values are arbitrary, not zero
    assert len(set(twin.offset)) > 1
    bank.close()


def test_joint_wiring_card_by_card():
    assert [qm.joint_channel(j) for j in range(6)] == [(0, 0), (0, 1), (0, 2), (0, 3), (1, 0), (1, 1)]
    bufs, twin, bank = make()
    twin.offset = [0] * 8
    twin.update([1, 2, 3, 4, 5, 6])
    assert bank.cards[0].read()[0] == [1, 2, 3, 4]
    assert bank.cards[1].read()[0] == [5, 6, 0, 0]
    bank.close()


def test_reset_and_latch_commands():
    bufs, twin, bank = make(1)
    twin.update([100, 200, 300, 400, 500, 600])
    before = bank.read_joints()[1]
    bank.reset_joints()
    raw, done = bank.read_joints()
    assert np.all(done == before)  # not executed until the card runs
    twin.update(None)
    raw, done = bank.read_joints()
    assert np.all(done == before + 1) and np.all(raw == 0)
    twin.update([110, 190, 300, 400, 500, 601])
    raw, _ = bank.read_joints()
    np.testing.assert_array_equal(raw, np.array([10, -10, 0, 0, 0, 1]) & qm.COUNTER_MASK)
    bank.cards[0].command(2, qm.CMD_LATCH)
    twin.update([0, 0, 777, 0, 0, 0])
    assert bank.cards[0].read_latch(2) == (777 - 300) & qm.COUNTER_MASK
    with pytest.raises(ValueError):
        bank.cards[0].command(0, 9)
    bank.close()


def test_not_a_card_is_refused():
    with pytest.raises(BadInput, match="not an encoder card"):
        Quad04Card(bytearray(qm.MAP_SIZE))
    with pytest.raises(BadInput, match="too small"):
        Quad04Card(bytearray(10))


def test_mem_url_round_trip_at_an_offset(tmp_path):
    path = tmp_path / "cards.bin"
    path.write_bytes(bytes(8192))
    with open(path, "r+b") as f:
        import mmap
        mm = mmap.mmap(f.fileno(), 8192)
        twin = Quad04Twin([memoryview(mm)[100:100 + qm.MAP_SIZE], memoryview(mm)[5000:5000 + qm.MAP_SIZE]],
                          np.random.default_rng(5))
        twin.update([1, 2, 3, 4, 5, 6])
        bank = open_bank([f"mem://{path}?offset=100", f"mem://{path}?offset=0x1388"])
        raw, _ = bank.read_joints()
        np.testing.assert_array_equal(raw, (np.arange(1, 7) + np.array(twin.offset[:6])) & qm.COUNTER_MASK)
        bank.reset_joints()
        twin.update(None)
        assert np.all(bank.read_joints()[0] == 0)
        assert not bank.replaced()
        bank.close()
        twin.release()
        mm.close()


@pytest.mark.parametrize("url", ["shm://", "shm://a/b", "mem://", "mem:///x?offset=abc", "mem:///x?size=3",
                                 "mem:///x?offset=-4", "tcp://x", "/dev/port", 7])
def test_bad_urls(url):
    with pytest.raises(BadInput):
        check_url(url)
    with pytest.raises(BadInput):
        open_card(url)


@pytest.mark.parametrize("url", ["shm://droid.{cell}.nocard", "mem://{tmp}/nothing?offset=0"])
def test_missing_cards_are_unavailable(tmp_path, cell_name, url):
    with pytest.raises(CardUnavailable):
        open_card(url.format(cell=cell_name, tmp=tmp_path))


def test_shm_card_and_replacement(cell_name):
    name = f"droid.{cell_name}.gmf1.quad0"
    shared = SharedCard(name)
    twin = Quad04Twin([shared.buf, bytearray(qm.MAP_SIZE)], np.random.default_rng(2))
    card = open_card(shared.url)
    try:
        twin.update([9, 0, 0, 0, 0, 0])
        assert card.read()[0][0] == (9 + twin.offset[0]) & qm.COUNTER_MASK
        assert card.powered and not card.replaced()
        twin.power(False)
        assert not card.powered
        twin.release()
        shared.close()  # the world goes away ...
        assert card.replaced()
        shared = SharedCard(name)  # ... and comes back with a new object under the same name
        assert card.replaced()
    finally:
        card.close()
        shared.close()
    assert not os.path.exists(f"/dev/shm/{name}")
    with pytest.raises(posix_ipc.ExistentialError):
        posix_ipc.SharedMemory("/" + name)
