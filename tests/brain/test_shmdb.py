"""Shared-memory databases: access, 0600, layout refusal, timeouts, dead-holder recovery."""
import multiprocessing as mp
import os
import signal
import stat
import time

import numpy as np
import pytest

from droid.brain.db import layouts as L
from droid.brain.db.shmdb import (Database, LockTimeout, MemoryDatabase, NoDatabase, cell_objects,
                               db_name, remove_cell_objects)
from droid.cli import BadInput

CTX = mp.get_context("fork")


@pytest.fixture
def db(cell_name):
    d = Database(db_name(cell_name, "arm1", "status"), L.ARM_STATUS_LAYOUT, create=True, timeout_s=0.3)
    yield d
    d.unlink()
    remove_cell_objects(cell_name)


def test_write_read_and_seq(db):
    s0 = db.seq
    db.update(x=12.5, encoder_pos=[1, 2, 3, 4, 5, 6], homed=L.HOMED)
    rec = db.read()
    assert float(rec["x"]) == 12.5
    assert list(rec["encoder_pos"]) == [1, 2, 3, 4, 5, 6]
    assert db.seq == s0 + 1
    assert int(rec["writer_pid"]) == os.getpid()
    assert int(rec["holder_pid"]) == os.getpid()  # the copy was taken under our lock
    assert int(np.frombuffer(db.raw_bytes(), L.HEADER, 1)[0]["holder_pid"]) == os.getpid()
    with open(f"/dev/shm{db.name}", "rb") as f:  # after release nobody holds it
        assert int(np.frombuffer(f.read(32), L.HEADER, 1)[0]["holder_pid"]) == 0


def test_second_attach_sees_same_bytes(db):
    db.update(busy=42)
    other = Database(db.name, L.ARM_STATUS_LAYOUT)
    try:
        assert int(other.read()["busy"]) == 42
        other.update(busy=7)
        assert int(db.read()["busy"]) == 7
    finally:
        other.close()


def test_objects_are_mode_0600(db, cell_name):
    entries = cell_objects(cell_name)
    assert len(entries) == 3  # shm object, semaphore, recovery semaphore
    for e in entries:
        assert stat.S_IMODE(os.stat(f"/dev/shm/{e}").st_mode) == 0o600, e


def test_wrong_layout_refused(db):
    with pytest.raises(L.LayoutError, match="expected arm_command"):
        Database(db.name, L.ARM_COMMAND_LAYOUT)


def test_other_version_refused(db):
    with db.locked() as v:
        v["version"] = 2
    with pytest.raises(BadInput, match="layout version 2"):
        Database(db.name, L.ARM_STATUS_LAYOUT)


def test_missing_database(cell_name):
    with pytest.raises(NoDatabase, match="is the cell up"):
        Database(db_name(cell_name, "nope", "status"), L.ARM_STATUS_LAYOUT)


@pytest.mark.parametrize("bad", ["", "a.b", "x" * 41, "sp ace", "../x"])
def test_bad_names_refused(bad):
    with pytest.raises(BadInput):
        db_name(bad, "arm1")


def _hold_forever(name, ready):
    d = Database(name, L.ARM_STATUS_LAYOUT)
    d._acquire()
    ready.set()
    time.sleep(60)


def _holder(target, name):
    """A process running ``target(name, ready)``, returned once it has set ``ready`` (killed if it never does)."""
    ready = CTX.Event()
    p = CTX.Process(target=target, args=(name, ready))
    p.start()
    if not ready.wait(10):
        p.kill()
        p.join()
        raise AssertionError(f"{target.__name__} did not get ready")
    return p


def test_live_holder_times_out(db):
    p = _holder(_hold_forever, db.name)
    try:
        t0 = time.monotonic()
        with pytest.raises(LockTimeout, match=f"held by pid {p.pid}"):
            db.read()
        assert time.monotonic() - t0 >= 0.25
    finally:
        p.kill()
        p.join()


def _waiter(name, start, results):
    d = Database(name, L.ARM_STATUS_LAYOUT, timeout_s=5.0)
    start.wait()
    took = []
    orig = d._take_over

    def spy(pid):
        ok = orig(pid)
        took.append(ok)
        return ok

    d._take_over = spy
    with d.locked() as v:
        v["busy"] = int(v["busy"]) + 1
        d.mark_written()
    results.put(sum(took))
    d.close()


def test_sigkilled_holder_recovered_by_exactly_one(db):
    holder = _holder(_hold_forever, db.name)
    start, results = CTX.Event(), CTX.Queue()
    waiters = [CTX.Process(target=_waiter, args=(db.name, start, results)) for _ in range(4)]
    for w in waiters:
        w.start()
    os.kill(holder.pid, signal.SIGKILL)
    holder.join()
    start.set()
    for w in waiters:
        w.join(20)
    takeovers = [results.get(timeout=5) for _ in waiters]
    assert all(w.exitcode == 0 for w in waiters)
    assert sum(takeovers) == 1  # exactly one party recovered the semaphore
    rec = db.read()
    assert int(rec["busy"]) == 4  # every waiter got its turn, nothing lost
    assert int(rec["flags"]) & L.FLAG_RECOVERED


def _die_without_pid(name, ready):
    d = Database(name, L.ARM_STATUS_LAYOUT)
    d._sem.acquire()  # taken, but killed before the holder pid is recorded
    ready.set()
    time.sleep(60)


def test_orphaned_semaphore_without_holder_recovered(db):
    p = _holder(_die_without_pid, db.name)
    os.kill(p.pid, signal.SIGKILL)
    p.join()
    db.update(busy=3)  # succeeds after two timeouts with no recorded holder
    assert int(db.read()["busy"]) == 3


def test_create_replaces_stale_object(db):
    db.update(busy=9)
    fresh = Database(db.name, L.ARM_STATUS_LAYOUT, create=True)
    try:
        assert int(fresh.read()["busy"]) == 0
    finally:
        fresh.close()


def test_memory_database_same_interface():
    m = MemoryDatabase("mem", L.ARM_COMMAND_LAYOUT)
    m.update(joint_time_count=5)
    rec = m.read()
    rec["cmd_id"] = 3
    m.write(rec)
    out = m.read()
    assert int(out["joint_time_count"]) == 5 and int(out["cmd_id"]) == 3 and m.seq == 2
    L.check_header(m.raw_bytes(), L.ARM_COMMAND_LAYOUT, "mem")


def test_priority_ceiling_holds_the_lock_at_fifo_61_and_restores_the_policy(cell_name):
    """Issue 16: a normal-priority reader holding a semaphore cannot be preempted by busy
    processes (it runs at the ceiling while it holds it), then drops back."""
    import os

    from droid.brain.db import shmdb
    from droid.brain.db.layouts import ARM_STATUS_LAYOUT

    name = f"/droid.{cell_name}.arm1.status"
    db = shmdb.Database(name, ARM_STATUS_LAYOUT, create=True)
    before = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
    try:
        shmdb.set_priority_ceiling(shmdb.CEILING_PRIORITY)
        with db.locked():
            inside = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
        after = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
        db.update(tick=5)
        assert int(db.read()["tick"]) == 5
        if shmdb._ceiling is None:  # the OS refused SCHED_FIFO: the ceiling switched itself off
            assert inside == before
        else:
            assert inside == (os.SCHED_FIFO, shmdb.CEILING_PRIORITY)
        assert after == before
    finally:
        shmdb.set_priority_ceiling(None)
        db.close()
        shmdb.unlink_database(name)
