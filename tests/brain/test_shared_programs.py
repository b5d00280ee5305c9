"""``[cell] share``: one process per host serves every subunit of that host that names a program
declared ``several`` -- droid-agent and droid-joystick (issue 28 item 4).  The cell file's key, the
programs droid-cell up starts, the programs' refusals, the host's demand, and (integration) a
live cell where each joystick keeps its own device, rate, Status and link through the shared
processes, and the shared agent's death stales exactly the subunits it served.
"""
from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

import pytest

from droid.brain.cell.cellfile import load_cell
from droid.brain.runtime.launcher import cell_programs
from droid.cli import BadInput
from tests.brain.cellutil import brought_down, cell_status, droid, in_process, make_cell_file, wait_for

SHARE = '["droid-agent", "droid-joystick"]'


def extra_joystick(k: int, rate_hz: float, x: float) -> str:
    """Subunit ``xjoyK`` on the Brain's host and its twin, as bench/bench_scale.py adds them, the
    twin's hand holding axis 0 at ``x`` (its table is the block's last: the key joins it)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    from bench_scale import joystick_block

    block = joystick_block(k, rate_hz)
    assert block.rstrip().rsplit("\n[", 1)[1].startswith(f"world.devices.xjoy_stick{k}]")
    return block + f"script = [[0.0, [{x}, 0.0], [0, 0, 0, 0, 0, 0, 0, 0]]]\n"


def shared_cell(tmp_path, name, share=SHARE, extra=2):
    """The built-in sim cell with ``[cell] share`` and ``extra`` joysticks of the Brain's host
    beside its own ``joy`` (xjoy0 at 30 Hz held at +0.3, xjoy1 at 100 Hz held at -0.5)."""
    holds = [(30.0, 0.3), (100.0, -0.5)]
    path = make_cell_file(tmp_path, name, extra="".join(extra_joystick(k, *holds[k % 2]) for k in range(extra)))
    text = path.read_text()
    assert "\n[cell]\n" in text
    path.write_text(text.replace("\n[cell]\n", f"\n[cell]\nshare = {share}\n", 1) if share else text)
    return path


def specs_of(path):
    first, rest = cell_programs(load_cell(path))
    return {s.key: (s.prog, s.args, s.host) for s in first + rest}


def test_without_share_each_subunit_has_its_own_processes(tmp_path, cell_name):
    specs = specs_of(shared_cell(tmp_path, cell_name, share=None))
    for sub in ("joy", "xjoy0", "xjoy1"):
        assert specs[f"agent-{sub}"] == ("droid-agent", [sub], "brain")
        assert specs[f"joystick-{sub}"] == ("droid-joystick", [sub], "brain")


def test_share_starts_one_process_a_host_for_its_subunits(tmp_path, cell_name):
    path = shared_cell(tmp_path, cell_name)
    assert load_cell(path).share == ("droid-agent", "droid-joystick")
    specs = specs_of(path)
    assert specs["agents-brain"] == ("droid-agent", ["joy", "xjoy0", "xjoy1"], "brain")
    assert specs["joysticks-brain"] == ("droid-joystick", ["joy", "xjoy0", "xjoy1"], "brain")
    # ft's agent is alone on its host (arm1): the key and process of an unshared one
    assert specs["agent-ft"] == ("droid-agent", ["ft"], "arm1")
    assert not any(k.startswith(("agent-joy", "agent-xjoy", "joystick-")) for k in specs)
    # programs not listed keep one process a subunit
    assert specs["reis-agent-arm1"] == ("droid-reis-agent", ["arm1"], "arm1")
    assert specs["remote-xjoy0"] == ("droid-remote", ["xjoy0"], "brain")


def test_the_host_warning_counts_a_shared_process_at_its_measured_cost(tmp_path, cell_name):
    from droid.brain.runtime.launcher import demand
    from droid.brain.cell.registry import program

    def asked(path):
        cell = load_cell(path)
        first, rest = cell_programs(cell)
        return demand(cell, first + rest).cpu_pct

    each = asked(shared_cell(tmp_path, cell_name, share=None))
    one = asked(shared_cell(tmp_path, cell_name))
    progs = [program(p) for p in ("droid-agent", "droid-joystick")]
    assert all(0 < p.cpu_pct_each < p.cpu_pct for p in progs)
    saved = sum(2 * (p.cpu_pct - p.cpu_pct_each) for p in progs)  # 3 subunits: 2 processes saved
    assert one == pytest.approx(each - saved)


@pytest.mark.parametrize("share, reason", [
    ('["droid-servo"]', "cannot serve several"),
    ('["droid-remote"]', "cannot serve several"),  # the Brain's: [brain] remotes says
    ('["droid-nosuch"]', "cannot serve several"),
    ('["droid-agent", "droid-agent"]', "twice"),
    ('"droid-agent"', "must be list"),
    ("[1]", "cannot serve several"),
])
def test_a_bad_share_is_refused_naming_the_key(tmp_path, cell_name, share, reason):
    with pytest.raises(BadInput) as exc:
        load_cell(shared_cell(tmp_path, cell_name, share=share))
    msg = str(exc.value)
    assert "[cell]" in msg and "share" in msg and reason in msg and "\n" not in msg


@pytest.mark.parametrize("module, argv, reason", [
    ("droid.subunits.agent", ["joy", "xjoy0", "joy"], "named twice"),
    ("droid.subunits.agent", ["joy", "ft"], "one process serves the subunits of one host"),
    ("droid.subunits.agent", ["joy", "nosuch"], "unknown subunit"),
    ("droid.subunits.joystick.prog", ["joy", "xjoy0", "xjoy0"], "named twice"),
    ("droid.subunits.joystick.prog", ["joy", "mvs"], "joystick"),
    ("droid.subunits.joystick.prog", [], "the following arguments are required"),
])
def test_the_shared_programs_refuse_a_bad_list_of_subunits(tmp_path, cell_name, capsys, module, argv, reason):
    import importlib

    path = shared_cell(tmp_path, cell_name)
    out = in_process(importlib.import_module(module).main, capsys, "--cell", str(path), *argv)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and reason in lines[0] and "Traceback" not in out.stderr, out.stderr


def _status(path, sub):
    out = droid("droid.tasks.snoop", sub, "--json", "--count", "1", "--rate", "20", "--cell", str(path))
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.mark.integration
def test_shared_agent_and_reader_keep_each_joystick_its_own(tmp_path, cell_name):
    path = shared_cell(tmp_path, cell_name)
    with brought_down(path, cell_name):
        out = droid("droid.brain.runtime.launcher", "up", "--cell", str(path), timeout=120)
        assert out.returncode == 0, out.stdout + out.stderr
        rows = {r["key"]: r for r in cell_status(path)}
        assert rows["agents-brain"]["name"] == "droid-agent joy xjoy0 xjoy1"
        assert rows["joysticks-brain"]["name"] == "droid-joystick joy xjoy0 xjoy1"
        assert "agent-joy" not in rows and "joystick-xjoy1" not in rows
        wait_for(lambda: all(r["live"] for r in cell_status(path)), what="every program live")
        # each joystick reads its own twin: the held deflections (joy's hand is centred)
        held = {"joy": 0.0, "xjoy0": 0.3, "xjoy1": -0.5}
        for sub, x in held.items():
            st = wait_for(lambda: (lambda d: not d["stale"] and d["valid"] and d["events"] > 0 and d)(
                _status(path, sub)), what=f"{sub} fresh and valid")
            assert st["axes"][0] == pytest.approx(x, abs=1e-3), (sub, st["axes"])
        # the shared agent dies: exactly the subunits it served go stale
        agent = rows["agents-brain"]["pid"]
        os.kill(agent, signal.SIGKILL)
        for sub in held:
            wait_for(lambda: _status(path, sub)["stale"], what=f"{sub} stale after the shared agent died")
        assert not _status(path, "ft")["stale"] and not _status(path, "arm1")["stale"]
        out = droid("droid.brain.runtime.launcher", "restart", "droid-agent joy xjoy0 xjoy1", "--cell", str(path),
                    timeout=60)
        assert out.returncode == 0, out.stderr
        for sub in held:
            wait_for(lambda: not _status(path, sub)["stale"], timeout=30, what=f"{sub} fresh again")
        # the reader kept running through it: the same process
        assert next(r["pid"] for r in cell_status(path) if r["key"] == "joysticks-brain") \
            == rows["joysticks-brain"]["pid"]
