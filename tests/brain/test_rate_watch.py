"""A program that cannot keep its rate says so (issue 28 item 4): RateWatch's windows, the
presence record's ``missed_pct``/``lagging`` and ``droid-cell status``'s row."""
from __future__ import annotations

import os
import io
import json
import re
import sys
import time
from pathlib import Path

from droid.brain.runtime import launcher
from droid.brain.cell.cellfile import builtin_cell_path, load_cell
from droid.brain.runtime.program import Presence, RateWatch
from droid.brain.db.shmdb import unlink_database
from tests.brain.cellutil import make_cell_file

S = 1_000_000_000  # ns


def watch():
    out = io.StringIO()
    return RateWatch("droid-remote arm1", out=out), out


def test_a_timer_program_that_keeps_its_rate_is_not_lagging():
    w, out = watch()
    w.update(0, 0, 0, 0)
    w.update(2 * S, 0, 1000, 0)  # 500 Hz, 2 s, nothing missed
    assert w.missed_pct == 0.0 and not w.lagging and out.getvalue() == ""


def test_a_timer_program_missing_periods_lags_and_says_so_then_recovers():
    w, out = watch()
    w.update(0, 0, 0, 0)
    w.update(1 * S, 0, 500, 90)  # inside the first window: nothing decided yet
    assert not w.lagging
    w.update(2 * S, 0, 900, 100)  # 900 run + 100 missed: 10 %
    assert w.lagging and abs(w.missed_pct - 10.0) < 1e-9
    assert "cannot keep its rate: missed 100 of 1000 periods (10.0 %) in the last 2.0 s" in out.getvalue()
    w.update(4 * S, 0, 1850, 150)  # 950 + 50: 5 %, the threshold itself
    assert w.lagging and out.getvalue().count("\n") == 1  # no repeat within REPEAT_S
    w.update(6 * S, 0, 2849, 151)  # 999 + 1: 0.1 %
    assert not w.lagging and w.missed_pct < 1.0
    assert "keeps its rate again (0.1 % missed in the last 2.0 s; lagged for 4 s)" in out.getvalue()


def test_lagging_is_repeated_in_the_log_at_most_every_repeat_s():
    w, out = watch()
    w.update(0, 0, 0, 0)
    cycles = missed = 0
    for k in range(1, 40):  # 78 s of 20 % missed
        cycles, missed = cycles + 800, missed + 200
        w.update(2 * k * S, 0, cycles, missed)
    lines = out.getvalue().splitlines()
    assert lines[0].endswith("(20.0 %) in the last 2.0 s")
    assert [ln.split("lagging for ")[1] for ln in lines[1:]] == ["30 s", "60 s"]


def test_a_tick_driven_program_counts_the_ticks_that_went_by():
    w, out = watch()
    w.update(0, 100, 5, 0)
    # 120 ticks went by (60 Hz, 2 s); it served 12 commands and missed 12 ticks: 10 %
    w.update(2 * S, 220, 17, 12)
    assert w.lagging and abs(w.missed_pct - 10.0) < 1e-9
    assert "missed 12 of 120 periods" in out.getvalue()


def test_no_periods_in_a_window_is_no_verdict():
    w, out = watch()
    w.update(0, 50, 0, 0)
    w.update(2 * S, 50, 0, 0)  # no tick went by (the heartbeat is silent: status shows the tick)
    assert w.missed_pct == 0.0 and not w.lagging and out.getvalue() == ""


def test_status_shows_a_lagging_program(tmp_path, cell_name, capsys, monkeypatch):
    path = make_cell_file(tmp_path, cell_name)
    cell = load_cell(path)
    pres = Presence(cell.name, "remote-arm1", "droid-remote arm1")
    try:
        pres.ready()
        now = [time.monotonic_ns() - 2 * S - S // 2]  # the last beat half a second ago: live
        monkeypatch.setattr("droid.brain.runtime.program.time.monotonic_ns", lambda: now[0])
        pres.rate.out = io.StringIO()
        pres.beat(1000, 0, 0)
        now[0] += 2 * S
        pres.beat(1120, 100, 30)  # 30 of 120 ticks missed
        monkeypatch.undo()
        rows = launcher.status(cell)
        row = next(r for r in rows if r["name"] == "droid-remote arm1")
        assert row["lagging"] is True and row["missed_pct"] == 25.0 and row["live"] is True
        assert launcher.main(["status", "--cell", str(path)]) == 0
        text = capsys.readouterr().out
        assert "LAGGING" in text and "missed 25.0 % of its periods" in text
        assert launcher.main(["status", "--json", "--cell", str(path)]) == 0
        got = json.loads(capsys.readouterr().out.splitlines()[0])
        assert list(got) == list(launcher.STATUS_KEYS) and got["lagging"] is True
    finally:
        pres.db.close()
        unlink_database(pres.name)


# -- droid-cell up: a cell that asks for more than the host can carry ---------------------
def _cell_with_joysticks(tmp_path, name, n):
    """The default cell plus ``n`` joysticks, as bench/bench_scale.py brings it up, named ``name``."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    from bench_scale import make_cell

    path = make_cell(tmp_path, builtin_cell_path(), n, 60.0)
    path.write_text(re.sub(r'(?m)^name = "[^"]*"', f'name = "{name}"', path.read_text(), count=1))
    return path


def _demand(path):
    first, rest = launcher.cell_programs(load_cell(path))
    return launcher.demand(load_cell(path), first + rest)


def test_the_default_cell_fits_two_cpus(tmp_path, cell_name, monkeypatch):
    monkeypatch.setattr(launcher.os, "sched_getaffinity", lambda pid: {0, 1})
    d = _demand(make_cell_file(tmp_path, cell_name))
    assert d.programs == 23 and d.cpus == 2  # droid-guard among them: the shipped cell runs the live guard
    # with the live collision guard off ([guard] run = false) droid-guard is not started
    unguarded = make_cell_file(tmp_path, cell_name + "g")
    unguarded.write_text(unguarded.read_text().replace("\nrun = true\n", "\nrun = false\n", 1))
    assert _demand(unguarded).programs == 22
    assert 80.0 < d.cpu_pct < 160.0  # every program and twin declares its cost
    assert d.warnings() == []


def test_a_cell_too_big_for_the_host_is_warned_of(tmp_path, cell_name, monkeypatch):
    path = _cell_with_joysticks(tmp_path, cell_name, 16)
    monkeypatch.setattr(launcher.os, "sched_getaffinity", lambda pid: {0, 1})
    d = _demand(path)
    assert d.programs == 23 + 3 * 16
    (line,) = d.warnings()
    assert line.startswith("its 71 programs need about ") and "this host's 2 CPUs" in line
    monkeypatch.setattr(launcher.os, "sched_getaffinity", lambda pid: set(range(8)))
    assert _demand(path).warnings() == []  # the same cell on 8 CPUs


def test_droid_cell_up_says_it_before_any_program_starts(tmp_path, cell_name, monkeypatch, capsys):
    path = _cell_with_joysticks(tmp_path, cell_name, 16)
    monkeypatch.setattr(launcher.os, "sched_getaffinity", lambda pid: {0, 1})
    started = []

    def no_start(cell, group, log_dir):
        started.append(len(group))
        raise launcher.RuntimeFailure("stopped by the test before any program started")

    monkeypatch.setattr(launcher, "_start", no_start)
    assert launcher.main(["up", "--force", "--cell", str(path)]) == 1  # over the RT budget too: --force
    err = capsys.readouterr().err
    assert f"droid-cell: warning: cell {cell_name}: its 71 programs need about" in err
    assert f"droid-cell: warning: cell {cell_name}: its SCHED_FIFO programs declare" in err
    assert "stopped by the test" in err and len(started) == 1


# -- the real-time budget (issue 40 item 1) ---------------------------------------------------
def test_the_default_cell_fits_the_real_time_budget_of_two_cpus_not_of_one(tmp_path, cell_name, monkeypatch):
    path = make_cell_file(tmp_path, cell_name)
    monkeypatch.setattr(launcher.os, "sched_getaffinity", lambda pid: {0, 1})
    d = _demand(path)
    assert set(d.fifo) >= {"droid-sim", "droid-servo", "droid-heartbeat", "droid-remote"}
    assert not set(d.fifo) & {"droid-mvs", "droid-gmf1-encoder", "droid-gmf1-agent", "droid-names"}  # nice, other
    assert 0 < d.fifo_pct < d.cpu_pct and d.fifo_pct_per_cpu == d.fifo_pct / 2
    assert d.fifo_pct_per_cpu <= launcher.RT_BUDGET_PCT_PER_CPU and d.over_rt_budget() is None
    monkeypatch.setattr(launcher.os, "sched_getaffinity", lambda pid: {0})  # taskset -c 0
    line = _demand(path).over_rt_budget()
    assert line is not None and "on 1 CPU:" in line and "droid-sim" in line and "\n" not in line


def test_a_cell_without_sched_fifo_asks_nothing_of_the_real_time_budget(tmp_path, cell_name, monkeypatch):
    path = _cell_with_joysticks(tmp_path, cell_name, 16)
    path.write_text(path.read_text().replace("sched_fifo = true", "sched_fifo = false", 1))
    monkeypatch.setattr(launcher.os, "sched_getaffinity", lambda pid: {0})
    d = _demand(path)
    assert d.fifo == {} and d.over_rt_budget() is None and d.cpu_pct > 100.0


def test_droid_cell_up_refuses_a_cell_over_the_real_time_budget_before_anything_is_made(
        tmp_path, cell_name, monkeypatch, capsys):
    from droid.brain.db.shmdb import cell_objects

    path = _cell_with_joysticks(tmp_path, cell_name, 16)  # 16 more agents and remotes at FIFO
    monkeypatch.setattr(launcher.os, "sched_getaffinity", lambda pid: {0, 1})
    started = []
    monkeypatch.setattr(launcher, "_start", lambda cell, group, log_dir: started.append(group))
    assert launcher.main(["up", "--cell", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith(f"droid-cell: cell {cell_name}: its SCHED_FIFO programs declare ")
    assert "over the real-time budget of 50 % a CPU (droid-" in err and "--force" in err
    assert started == [] and cell_objects(cell_name) == []  # no program, no database


def test_every_builtin_program_and_twin_declares_its_cost():
    from droid.brain.cell.registry import BUILTIN_PACKAGES, registry

    reg = registry()
    for pkg in reg.packages.values():
        if pkg.name not in BUILTIN_PACKAGES:
            continue
        for p in pkg.programs:
            if p.role != "tool":
                assert p.cpu_pct > 0 and p.rss_mb > 0, p.name
        for t in pkg.twins:
            assert t.cpu_pct > 0, t.type


def test_status_measures_a_programs_share_and_scheduler_from_proc():
    sched, cpu = launcher.measured_cpu(os.getpid())
    assert sched == ("nice" if os.getpriority(os.PRIO_PROCESS, 0) < 0 else "other") and 0.0 <= cpu <= 200.0
    assert launcher.measured_cpu(2 ** 22 + 12345) == (None, None)  # no such process
    assert {"sched", "cpu_pct", "lateness_max_ms"} <= set(launcher.STATUS_KEYS)
