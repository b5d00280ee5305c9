"""A cell file in lockstep, every class (issue 25 item 2; droid.sim.lockstep_cell, droid.sim.lockstep_build).

Every built-in device package's lockstep slot builds its subunits from a cell file; the bundled
cells run and their arms home through their Brain Command records as droid-home writes them; a
user's cell (three arms, one of them a robot file of its own, two joysticks) builds and runs;
bad input is one line naming the file and the subunit, exit 2, nothing built.  No verdict reads
a clock: only virtual time.
"""
from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from droid.brain.db import arm_command
from droid.brain.cell.cellfile import BUNDLED_CELLS
from droid.brain.cell.registry import registry, resolve
from droid.cli import BadInput
from droid.sim.lockstep_cell import build_lockstep_cell, status_summary
from tests.robot_files import spoiled

SIM = BUNDLED_CELLS / "sim.toml"
PAIR = BUNDLED_CELLS / "reis_pair.toml"
ABB = BUNDLED_CELLS / "abb_weld.toml"
ROBOTS = Path(__file__).resolve().parents[2] / "droid" / "kinematics" / "robots"


def home_all(lc, max_s: float = 60.0) -> dict[str, bool]:
    """droid-home on every arm at once through its Brain Command record; run until each Brain
    Status says homed, idle and acknowledged (``max_s`` virtual seconds at most)."""
    lc.run_for(0.1)  # the cell is up before a task writes (droid-home runs after droid-cell up)
    ids = {n: arm_command.home(s.command) for n, s in lc.subunits.items() if s.arm is not None}

    def homed(n: str) -> bool:
        st = lc.subunits[n].status.read()
        return bool(int(st["homed"]) and int(st["cmd_id"]) == ids[n] and not int(st["busy"]))

    end = lc.sched.t_s + max_s
    while lc.sched.t_s < end and not all(homed(n) for n in ids):
        lc.run_for(0.5)
    return {n: homed(n) for n in ids}


def test_every_builtin_package_registers_one_builder():
    reg = registry()
    for name in ("reis", "gmf1", "abb", "mvs", "joystick", "ft"):
        build = resolve(reg.packages[name].lockstep)
        assert callable(build) and build.programs, name
        own = {p.name for p in reg.packages[name].programs if p.role == "cell"}
        assert own <= set(build.programs), (name, own - set(build.programs))


def test_sim_cell_builds_every_class_and_runs():
    with build_lockstep_cell(SIM) as lc:
        assert {n: s.cls for n, s in lc.subunits.items()} == {
            "arm1": "arm6r", "gmf1": "arm6r", "mvs": "line_laser", "tool": "line_laser", "joy": "joystick",
            "ft": "ft6"}
        assert type(lc.subunits["arm1"].parts).__name__ == "LockstepArm"
        assert type(lc.subunits["gmf1"].parts).__name__ == "Gmf1Lockstep"
        for s in lc.subunits.values():  # the Brain's records, the layouts droid-cell up makes in shm
            assert s.status.layout is registry().classes[s.cls].brain["status"]
        lc.run_for(2.0)
        assert lc.sched.tick == 120
        for s in lc.subunits.values():
            st = s.status.read()
            assert int(st["tick"]) == 120 and int(st["stale"]) == 0, s.name
        # stations at their declared rates (the registry's Program table)
        tasks = lc.sched.tasks
        assert tasks["arm1.servo"].rate_hz == registry().programs["droid-servo"].rate_hz
        assert tasks["gmf1.encoder"].rate_hz == registry().programs["droid-gmf1-encoder"].rate_hz
        assert tasks["joy.joystick"].rate_hz == registry().programs["droid-joystick"].rate_hz
        assert tasks["mvs.mvs_sensor"].rate_hz == registry().programs["droid-mvs"].rate_hz
        ft = lc.subunits["ft"].status.read()  # the tool's weight on the Reis wrist
        assert int(ft["valid"]) == 1 and 5.0 < np.linalg.norm(ft["force_N"]) < 30.0
        # the workpiece on the Fanuc pushes back on the Reis's tool (world device "touch")
        assert lc.subunits["arm1"].parts.plant.contact is not None


def test_sim_cell_arms_home_through_the_brain_databases():
    with build_lockstep_cell(SIM) as lc:
        assert home_all(lc) == {"arm1": True, "gmf1": True}
        for n in ("arm1", "gmf1"):  # the remote's forward kinematics, once homed (§4.1.8)
            st = lc.subunits[n].status.read()
            assert np.hypot(float(st["x"]), float(st["z"])) > 100.0


def test_reis_pair_arms_home_through_the_brain_databases():
    with build_lockstep_cell(PAIR) as lc:
        assert lc.subunits["arm2"].parts.model.name == "reis_class_b"
        assert home_all(lc) == {"arm1": True, "arm2": True}


def test_abb_cell_builds_its_arm_and_sensors():
    with build_lockstep_cell(ABB) as lc:
        kinds = {n: type(s.parts).__name__ for n, s in lc.subunits.items()}
        assert "LockstepAbbArm" in kinds.values() and "Gmf1Lockstep" in kinds.values()
        lc.run_for(1.0)
        assert all(int(s.status.read()["tick"]) == 60 for s in lc.subunits.values())


USER_CELL = """\
[cell]
name = "usercell"
run_dir = "@TMP@/run"
heartbeat_hz = 60.0

[world]
enabled = true
seed = 3

[world.devices.arm1]
type = "reis_vme"
subunit = "arm1"

[world.devices.stick_a]
type = "joystick"
device = "{run}/joy_a.js"
axes = 3
buttons = 4
script = [[0.5, [0.5, 0.25, 1.0], [1, 0, 0, 1]]]  # (a negative axis value: droid.numbers reads "script" as amperes)

[world.devices.stick_b]
type = "joystick"
device = "{run}/joy_b.js"
""" + "".join(f"""
[subunits.{name}]
class = "arm6r"
robot = "{robot}"
host = "{name}"
agent = "ipc://{{run}}/{name}.agent"
relay = "ipc://{{run}}/{name}.relay"
base = [{x}, 0.0, 0.0, 0.0, 0.0, 0.0]
programs = ["droid-watchdog", "droid-servo", "droid-servo-agent", "droid-reis-agent", "droid-planner"]
vme = "shm://droid.{{cell}}.{name}.vme"
""" for name, robot, x in (("arm1", "reis_v15", 0.0), ("arm2", "reis_class_b", 2500.0),
                           ("arm3", "@ROBOT@", -2500.0))) + "".join(f"""
[subunits.{name}]
class = "joystick"
host = "brain"
agent = "ipc://{{run}}/{name}.agent"
relay = "ipc://{{run}}/{name}.relay"
device = "js://{{run}}/{name}.js"
programs = ["droid-joystick", "droid-agent"]
""" for name in ("joy_a", "joy_b"))


def user_cell(tmp_path: Path) -> Path:
    """Three arms (one a robot file of the user's own), two joysticks; arm2 and arm3 have no
    world device (the world is on: their VME maps are shm:// -- so one each is needed for
    droid-cell up; lockstep reads the same file)."""
    robot = spoiled(ROBOTS / "reis_class_b.toml", tmp_path, 'name = "reis_class_b"', 'name = "lab_arm"')
    text = USER_CELL.replace("@TMP@", str(tmp_path)).replace("@ROBOT@", str(robot))
    text += "".join(f'\n[world.devices.{n}]\ntype = "reis_vme"\nsubunit = "{n}"\n' for n in ("arm2", "arm3"))
    p = tmp_path / "usercell.toml"
    p.write_text(text)
    return p


def test_the_ft_sensor_biases_and_guards_its_arm_through_the_brain():
    """droid-ft's whole cycle in lockstep (issue 25 item 3): its station calibrates from the twin's
    page and starts the stream; a task's bias and over-force limit go through the Brain Command,
    droid-remote and droid-agent; the guard sets FAULT_FORCE in arm1's own Status, and a
    limit of 0 clears it, with the lines droid-ft would print."""
    from droid.brain.db.layouts import FAULT_FORCE

    with build_lockstep_cell(SIM) as lc:
        ft, arm1 = lc.subunits["ft"], lc.subunits["arm1"].parts
        lc.run_for(1.0)
        st = ft.status.read()
        assert int(st["valid"]) == 1 and int(st["biased"]) == 0
        weight_n = float(np.linalg.norm(st["force_N"]))
        assert weight_n > 5.0  # the torch hangs on the sensor: its weight, before the bias

        def command(**fields) -> None:
            with ft.command.locked() as c:
                for k, v in fields.items():
                    c[k] = v
                c["cmd_id"] = int(c["cmd_id"]) + 1
                c["sent"] = 1
                ft.command.mark_written()

        command(bias_id=1)
        lc.run_for(0.5)
        st = ft.status.read()
        assert int(st["biased"]) == 1 and float(np.linalg.norm(st["force_N"])) < 0.05 * weight_n
        assert not int(arm1.ctrl_status.read()["fault"]) & FAULT_FORCE
        command(guard_force_n=1e-6)  # any reading is over it
        lc.run_for(0.5)
        assert int(arm1.ctrl_status.read()["fault"]) & FAULT_FORCE
        command(guard_force_n=0.0)
        lc.run_for(0.5)
        assert not int(arm1.ctrl_status.read()["fault"]) & FAULT_FORCE
        lines = ft.parts.lines
        assert any(line.startswith("calibration:") for line in lines), lines
        assert any("over-force guard tripped on arm1" in line for line in lines), lines
        assert any("over-force guard clear on arm1" in line for line in lines), lines


def test_a_users_cell_three_arms_two_joysticks_a_robot_file(tmp_path):
    with build_lockstep_cell(user_cell(tmp_path)) as lc:
        assert sorted(lc.subunits) == ["arm1", "arm2", "arm3", "joy_a", "joy_b"]
        assert lc.subunits["arm3"].parts.model.name == "lab_arm"
        lc.run_for(1.0)
        a = lc.subunits["joy_a"].status.read()
        assert [round(float(v), 3) for v in a["axes"][:3]] == [0.5, 0.25, 1.0]
        assert list(a["buttons"][:4]) == [1, 0, 0, 1] and int(a["n_axes"]) == 3
        b = lc.subunits["joy_b"].status.read()
        assert int(b["valid"]) == 1 and not np.any(b["axes"])
        assert home_all(lc) == {"arm1": True, "arm2": True, "arm3": True}


def test_the_joystick_status_follows_its_twin(tmp_path):
    with build_lockstep_cell(user_cell(tmp_path)) as lc:
        joy = lc.subunits["joy_b"]
        lc.run_for(0.2)
        before = joy.status.read()
        joy.parts.twin.move(axes=[-0.75, 0.25], buttons=[0, 1])
        lc.run_for(0.1)  # the station's next cycle, then the agent's reply on the next tick
        after = joy.status.read()
        assert not np.any(before["axes"]) and int(before["events"]) < int(after["events"])
        assert [round(float(v), 3) for v in after["axes"][:2]] == [-0.75, 0.25]
        assert list(after["buttons"][:2]) == [0, 1]


def test_a_program_the_subunit_does_not_run_does_not_run(tmp_path):
    text = SIM.read_text().replace('programs = ["droid-joystick", "droid-agent"]', 'programs = ["droid-agent"]')
    p = tmp_path / "nostick.toml"
    p.write_text(text)
    with build_lockstep_cell(p) as lc:
        assert "joy.joystick" not in lc.sched.tasks and list(lc.subunits["joy"].stations) == ["droid-agent"]


# -- bad input: one line, exit 2, nothing built ----------------------------------------------
def bad_cell(tmp_path: Path, old: str, new: str) -> Path:
    text = SIM.read_text()
    assert old in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(old, new, 1))
    return p


NO_STATION = ('programs = ["droid-gmf1-agent", "droid-gmf1-serial", "droid-gmf1-encoder"]',
              'programs = ["droid-gmf1-agent", "droid-gmf1-serial", "droid-gmf1-encoder", "droid-agent"]')


@pytest.mark.parametrize("old, new, words", [
    (*NO_STATION, ["[subunits.gmf1]", "program 'droid-agent' has no lockstep station"]),
    ('programs = ["droid-watchdog", "droid-servo", "droid-servo-agent", "droid-reis-agent", "droid-planner"]',
     'programs = ["droid-servo", "droid-gmf1-serial"]',
     ["[subunits.arm1]", "no one lockstep builder stands for all its programs"]),
    ('class = "ft6"', 'class = "flux_capacitor"', ["[subunits.ft]", "unknown class 'flux_capacitor'"]),
])
def test_bad_input_is_one_line_naming_file_and_subunit(tmp_path, old, new, words):
    p = bad_cell(tmp_path, old, new)
    with pytest.raises(BadInput) as exc:
        build_lockstep_cell(p)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"{p}: [subunits.")
    for w in words:
        assert w in msg, msg


def test_nothing_is_built_when_a_later_subunit_is_bad(tmp_path, monkeypatch):
    """Every builder is chosen before the first is called: arm1 comes before the bad gmf1 and is
    not built."""
    import droid.sim.reis.cell as reis_cell

    calls = []
    monkeypatch.setattr(reis_cell, "LockstepArm", lambda *a, **k: calls.append(a))
    with pytest.raises(BadInput, match="no lockstep station"):
        build_lockstep_cell(bad_cell(tmp_path, *NO_STATION))
    assert calls == []


# -- the CLI: droid-sim lockstep ----------------------------------------------------------------
def test_cli_prints_each_subunits_status(capsys):
    from droid.sim.world import main

    assert main(["lockstep", str(PAIR), "--seconds", "0.5", "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(r["subunit"], r["class"], r["tick"], r["stale"]) for r in rows] == [
        ("arm1", "arm6r", 30, 0), ("arm2", "arm6r", 30, 0)]
    assert main(["lockstep", str(PAIR), "--seconds", "0.1"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("arm1 (arm6r): tick=6  stale=0")


@pytest.mark.parametrize("args, words", [
    ([], ["CELL"]),
    (["--seconds", "-1"], ["--seconds"]),
    (["--seconds", "nan"], ["--seconds"]),
])
def test_cli_bad_arguments_exit_2(capsys, args, words):
    from droid.sim.world import main

    argv = ["lockstep"] + ([str(PAIR)] if args else []) + args
    with pytest.raises(SystemExit) as exc:  # argparse's one-line error (droid.cli.ArgumentParser)
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(w in err for w in words), err


def test_cli_bad_cell_is_one_line_exit_2(tmp_path, capsys):
    from droid.sim.world import main

    p = bad_cell(tmp_path, *NO_STATION)
    assert main(["lockstep", str(p), "--seconds", "1"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert f"{p}: [subunits.gmf1] program 'droid-agent' has no lockstep station" in err


def test_status_summary_is_plain_json():
    with build_lockstep_cell(PAIR) as lc:
        row = status_summary(lc.subunits["arm1"])
        assert json.loads(json.dumps(row))["subunit"] == "arm1" and "R" not in row


def test_a_task_builds_only_what_it_needs_and_starts_the_rest_in_its_order():
    """build_lockstep_cell(..., sched=, subunits=) builds the named subunits on a task's own
    scheduler; LockstepCell.add starts another on the running scheduler (a declared start order:
    the seam-tracking trial's holder starts once its welder is homed)."""
    from droid.sim.lockstep import Scheduler

    sched = Scheduler(60.0)
    with build_lockstep_cell(ABB, 5, sched=sched, subunits={"abb": None}) as lc:
        assert lc.sched is sched and list(lc.subunits) == ["abb"] and lc.ctx.seed == 5
        lc.run_for(1.0)
        gmf1 = lc.add("gmf1")
        assert list(lc.subunits) == ["abb", "gmf1"] and gmf1.arm.name == "gmf1"
        lc.run_for(0.5)
        assert int(lc.subunits["abb"].status.read()["tick"]) == 90
        encoder = sched.tasks[gmf1.stations["droid-gmf1-encoder"][0]]  # 120 Hz, from the instant it was added
        assert encoder.start_ns == 1_000_000_000 and encoder.k == 61  # 1 s, 1 s + 1/120 s, ..., 1.5 s
