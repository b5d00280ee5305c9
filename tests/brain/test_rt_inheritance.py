"""Real-time scheduling does not leak: not out of a test into the pytest process, not from a
real-time parent into the cell programs it starts (issue 16).

A program's ``main()`` run in-process switched pytest to SCHED_FIFO 48 with its memory
locked; every later test, and every process those tests started, then ran at FIFO
priority, and a cell's sixteen programs importing numpy at FIFO priority on two cores set
off the kernel's RT throttling and latched the arms' watchdogs at start-up.
"""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from droid.brain.runtime.rt import normal_scheduler, try_sched_fifo
from tests.conftest import scheduler_leak

needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO needs root (CI and this VM run as root)")


@needs_root
def test_the_leak_check_sees_fifo_and_locked_memory_and_normal_scheduler_clears_both():
    assert scheduler_leak() is None
    try:
        assert try_sched_fifo(wanted=True, prog="droid-planner")
        leak = scheduler_leak()
        assert leak is not None and "priority 51" in leak and "locked memory" in leak
    finally:
        normal_scheduler()
    assert scheduler_leak() is None


@needs_root
def test_a_nice_program_stays_on_the_normal_scheduler_at_its_nice_level_and_the_leak_check_sees_it():
    from droid.brain.runtime.rt import NICE_LEVEL

    assert scheduler_leak() is None
    try:
        assert not try_sched_fifo(wanted=True, prog="droid-mvs")  # sched = "nice": not real-time
        assert os.sched_getscheduler(0) == os.SCHED_OTHER
        assert os.getpriority(os.PRIO_PROCESS, 0) == NICE_LEVEL
        leak = scheduler_leak()
        assert leak is not None and f"nice {NICE_LEVEL}" in leak and "locked memory" in leak
    finally:
        normal_scheduler()
    assert scheduler_leak() is None and os.getpriority(os.PRIO_PROCESS, 0) == 0


@needs_root
@pytest.mark.integration  # starts a cell program (and runs pytest at FIFO 20 for a moment)
def test_launcher_starts_programs_on_the_normal_scheduler_from_a_fifo_parent(tmp_path, cell_name):
    """droid-cell's children start on SCHED_OTHER even when droid-cell itself runs at FIFO
    priority; each program asks for FIFO itself once its imports are done."""
    from droid.brain.cell.cellfile import load_cell
    from droid.brain.runtime.launcher import Spec, _start
    from tests.brain.cellutil import make_cell_file

    cell = load_cell(str(make_cell_file(tmp_path, cell_name)))
    log_dir = tmp_path / "logs"
    log_dir.mkdir()
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(20))
    try:
        # droid-names never asks for FIFO: whatever policy it has, it inherited
        started = _start(cell, [Spec("names", "droid-names", [], cell.brain_host)], str(log_dir))
    finally:
        normal_scheduler()
    (r, (spec, proc)), = started.items()
    try:
        assert os.sched_getscheduler(proc.pid) == os.SCHED_OTHER
    finally:
        proc.kill()
        proc.wait(10)
        os.close(r)
    # and a plain child of a FIFO parent does inherit it (what the launcher guards against)
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(20))
    try:
        out = subprocess.run([sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"],
                             capture_output=True, text=True, timeout=30)
    finally:
        normal_scheduler()
    assert out.stdout.strip() == str(os.SCHED_FIFO)
