"""``[brain] remotes = "one"``: one droid-remote process serves every agent-linked subunit
(issue 28 item 4).  The cell file's key, the programs droid-cell up starts, droid-remote's
refusals, and (integration) a live cell where each subunit keeps its own link: one agent's
death makes only its subunit stale, and commands still reach every arm.
"""
from __future__ import annotations

import json
import os
import signal

import pytest

from droid.brain.cell.cellfile import load_cell
from droid.brain.runtime.launcher import cell_programs
from droid.cli import BadInput
from tests.brain.cellutil import brought_down, cell_status, droid, in_process, make_cell_file, wait_for



def one_remote_cell(tmp_path, name, remotes='"one"'):
    """The built-in sim cell with ``[brain] remotes`` set (its own [brain] table gains the key)."""
    path = make_cell_file(tmp_path, name)
    text = path.read_text()
    assert "\n[brain]\n" in text
    path.write_text(text.replace("\n[brain]\n", f"\n[brain]\nremotes = {remotes}\n", 1))
    return path


def remote_specs(path):
    first, rest = cell_programs(load_cell(path))
    return [s for s in first + rest if s.prog == "droid-remote"]


def test_each_subunit_has_its_remote_by_default(tmp_path, cell_name):
    specs = remote_specs(make_cell_file(tmp_path, cell_name))
    assert sorted(s.key for s in specs) == sorted(f"remote-{n}" for n in load_cell(
        make_cell_file(tmp_path, cell_name)).subunits)
    assert all(len(s.args) == 1 for s in specs)


def test_one_remote_serves_the_agent_linked_subunits_and_serial_sensors_keep_theirs(tmp_path, cell_name):
    path = one_remote_cell(tmp_path, cell_name)
    cell = load_cell(path)
    assert cell.remotes == "one"
    specs = {s.key: s.args for s in remote_specs(path)}
    serial = {n for n, s in cell.subunits.items() if s.options.get("link") == "serial"}
    assert serial, "the built-in cell has serial-linked sensors"
    assert specs.pop("remote") == [n for n in cell.subunits if n not in serial]
    assert specs == {f"remote-{n}": [n] for n in serial}


def test_the_host_warning_counts_one_remote_at_its_measured_cost(tmp_path, cell_name):
    """droid-cell up's demand (issue 28 item 4): the shared remote declares its own cost plus a
    share per further subunit, so the same cell asks for less with it, but not for nothing."""
    from droid.brain.runtime.launcher import demand
    from droid.brain.cell.registry import program

    def asked(path):
        cell = load_cell(path)
        first, rest = cell_programs(cell)
        return demand(cell, first + rest).cpu_pct

    each = asked(make_cell_file(tmp_path, cell_name))
    one = asked(one_remote_cell(tmp_path, cell_name))
    p = program("droid-remote")
    assert 0 < p.cpu_pct_each < p.cpu_pct
    saved = 3 * (p.cpu_pct - p.cpu_pct_each)  # 4 remotes -> 1
    assert one == pytest.approx(each - saved)


@pytest.mark.parametrize("value", ['"two"', '"ONE"', "1", '""'])
def test_a_bad_remotes_value_is_refused_naming_the_key(tmp_path, cell_name, value):
    path = one_remote_cell(tmp_path, cell_name, value)
    with pytest.raises(BadInput) as exc:
        load_cell(path)
    msg = str(exc.value)
    assert "[brain]" in msg and "remotes" in msg and "\n" not in msg


@pytest.mark.parametrize("argv, reason", [
    (["arm1", "gmf1", "arm1"], "named twice"),
    (["arm1", "mvs"], "serial-linked"),
    (["arm1", "nosuch"], "unknown subunit"),
    ([], "the following arguments are required"),
])
def test_droid_remote_refuses_a_bad_list_of_subunits(tmp_path, cell_name, capsys, argv, reason):
    from droid.brain.runtime import remote

    path = make_cell_file(tmp_path, cell_name)
    out = in_process(remote.main, capsys, "--cell", str(path), *argv)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and reason in lines[0] and "Traceback" not in out.stderr


def _status(path, sub):
    out = droid("droid.tasks.snoop", sub, "--json", "--count", "1", "--rate", "20", "--cell", str(path))
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.mark.integration
def test_one_remote_keeps_every_subunit_in_step_and_a_dead_agent_stales_only_its_own(tmp_path, cell_name):
    path = one_remote_cell(tmp_path, cell_name)
    with brought_down(path, cell_name):
        out = droid("droid.brain.runtime.launcher", "up", "--cell", str(path), timeout=120)
        assert out.returncode == 0, out.stdout + out.stderr
        rows = cell_status(path)
        names = {r["name"] for r in rows}
        shared = [r["name"] for r in rows if r["key"] == "remote"]
        assert shared == ["droid-remote arm1 gmf1 joy ft"], shared  # the agent-linked subunits
        assert "droid-remote arm1" not in names
        assert {"droid-remote mvs", "droid-remote tool"} <= names  # serial-linked: their own
        wait_for(lambda: all(r["live"] for r in cell_status(path)), what="every program live")
        subs = list(load_cell(path).subunits)
        for sub in subs:
            wait_for(lambda: not _status(path, sub)["stale"], what=f"{sub} fresh")
        # a command through the shared remote: the GMF1 homes
        home = droid("droid.tasks.home", "gmf1", "--cell", str(path), timeout=120)
        assert home.returncode == 0, home.stderr
        # gmf1's agent dies: gmf1 goes stale, the others stay fresh
        agent = next(r for r in cell_status(path) if r["name"] == "droid-gmf1-agent gmf1")
        os.kill(agent["pid"], signal.SIGKILL)
        wait_for(lambda: _status(path, "gmf1")["stale"], what="gmf1 stale after its agent died")
        others = [s for s in subs if s != "gmf1"]
        assert [s for s in others if _status(path, s)["stale"]] == []
        # restarted, its link comes back through the same remote process
        remote_pid = next(r["pid"] for r in cell_status(path) if r["key"] == "remote")
        out = droid("droid.brain.runtime.launcher", "restart", "droid-gmf1-agent gmf1", "--cell", str(path), timeout=60)
        assert out.returncode == 0, out.stderr
        wait_for(lambda: not _status(path, "gmf1")["stale"], timeout=30, what="gmf1 fresh again")
        assert next(r["pid"] for r in cell_status(path) if r["key"] == "remote") == remote_pid
