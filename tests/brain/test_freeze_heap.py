"""A program's start-up heap is frozen before its loop (droid.brain.runtime.rt.freeze_heap, issue 40).

A full pass of CPython's cyclic collector walks every tracked object; frozen objects (the
permanent generation) are not walked.  Run in child processes, since freezing is process-wide.
Each child imports what a cell program imports, builds some garbage cycles, then ends its
start-up the way a program does: ``notify_ready`` (every cell program) or ``try_sched_fifo``
(every task and real-time program), and reports the frozen count and how many objects a full
pass would still walk.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

CHILD = r"""
import gc, json, sys, weakref
import numpy  # what every program imports
import droid.brain.runtime.program as program
from droid.brain.runtime.rt import try_sched_fifo

class Node:
    pass

alive = weakref.WeakSet()

def cycles(n):  # garbage a collection frees (and a freeze without one would keep for ever)
    for _ in range(n):
        a, b = Node(), Node()
        a.other, b.other = b, a
        alive.add(a)
        alive.add(b)

cycles(5000)
walked_before = len(gc.get_objects())
if sys.argv[1] == "ready":
    program.notify_ready(None)
else:
    try_sched_fifo(wanted=False, prog="test")
frozen = gc.get_freeze_count()
garbage_kept = len(alive)
cycles(10)
print(json.dumps({"frozen": frozen, "walked_before": walked_before, "walked_after": len(gc.get_objects()),
                  "garbage_kept": garbage_kept}))
"""


def child(how: str, **env) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, how], capture_output=True, text=True, timeout=120,
                         env={**os.environ, **env})
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_notify_ready_collects_then_freezes_the_start_up_heap():
    got = child("ready")
    assert got["frozen"] > 10_000, got  # numpy, pyzmq, the cell layer: tens of thousands of objects
    # a full pass after the freeze walks only what was made since (the ten new cycles), not the start-up
    assert got["walked_after"] < got["walked_before"] / 20, got
    # the 5000 garbage cycles were collected before the freeze: none of them was frozen (kept for ever)
    assert got["garbage_kept"] == 0, got


def test_a_task_entering_its_loop_freezes_too():
    got = child("task")
    assert got["frozen"] > 10_000, got
    assert got["walked_after"] < got["walked_before"] / 20, got


def test_the_freeze_can_be_switched_off_for_measuring():
    got = child("ready", DROID_NO_GC_FREEZE="1")
    assert got["frozen"] == 0, got
    assert got["walked_after"] >= got["walked_before"] - 11_000, got  # the cycles collected, the rest walked
