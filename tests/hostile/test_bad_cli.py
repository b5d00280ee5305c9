"""Hostile command lines (issue 8; docs/design.md §6): every bad invocation exits 2 with exactly one
line on stderr naming the reason, never a traceback, and the robot does not move.

The session's shared simulated cell, both arms homed (tests/conftest.py).  Each
invocation aimed at it (droid-move, droid-home, droid-jog) is then checked for
"no motion": the Brain's arm1 Command record is byte for byte unchanged with
the same write counter (no command, no command id written), and the arm's
encoder_cmd is unchanged and its encoder_pos within 3 counts (servo noise).
The programs' mains run in this process (fast); tests/tasks/test_move_input.py,
tests/brain/test_cli_input.py and tests/kinematics/test_kin_cli.py hold the
cases not repeated here.
"""
from __future__ import annotations

import io
import sys

import numpy as np
import pytest

from droid.brain.db import layouts as L
from droid.brain.cell.cellfile import load_cell
from droid.brain.db.databases import open_brain, open_local
from droid.brain.db.shmdb import cell_objects
from tests.brain.cellutil import make_cell_file, wait_for

pytestmark = pytest.mark.integration


@pytest.fixture
def live(homed_sim_cell):
    """The session's shared homed cell (tests/conftest.py ``homed_sim_cell``)."""
    return homed_sim_cell


#: the Brain Command's fields a task writes: all but the header and the collision guard's own two,
#: which droid-guard stamps every heartbeat tick (docs/guard.md §7a) -- so the record's write counter
#: moves with the guard too, and a task's write shows in these fields (its cmd_id at least)
TASK_FIELDS = [n for n in L.ARM_COMMAND.names if n not in {f[0] for f in L.HEADER_FIELDS}
               and n not in ("guard_tick", "guard_override")]


def arm_state(path):
    """(the Brain Command's task fields as bytes, their cmd_id, Status encoder_cmd, encoder_pos,
    ctrl cmd_id)."""
    cell = load_cell(path)
    sub = cell.subunit("arm1")
    with open_brain(cell, sub, "command") as cmd, open_brain(cell, sub, "status") as st, \
            open_local(cell, sub, "ctrl_command") as cc:
        c = cmd.read()
        rec = st.read()
        return (b"".join(np.asarray(c[n]).tobytes() for n in TASK_FIELDS), int(c["cmd_id"]),
                np.array(rec["encoder_cmd"]), np.array(rec["encoder_pos"]), int(cc.read()["cmd_id"]))


def settled(path):
    """arm1 idle and homed, its Status fresh (so a later comparison means something)."""
    def ok():
        cell = load_cell(path)
        with open_brain(cell, cell.subunit("arm1"), "status") as st:
            r = st.read()
            return int(r["homed"]) and not int(r["busy"]) and not int(r["stale"])
    wait_for(ok, timeout=30, what="arm1 homed, idle and fresh")


def call(main, argv, capsys, monkeypatch, stdin: str | None = None):
    """Run a program's main in this process: (exit code, stderr)."""
    if stdin is not None:
        monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's error() exits
        code = exc.code
    return code, capsys.readouterr().err


def assert_one_line(code, err, reason):
    assert code == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert reason in lines[0], err


# ------------------------------------------------------------------ aimed at the live cell

JOINT0 = ["0", "0", "0", "0", "0"]
START = ["300", "100", "1340", "0", "180", "0"]
LIVE = [  # (program, argv, stdin, reason)
    ("move", ["arm1", "joint", *JOINT0, "１２", "1"], None, "not a number"),
    ("move", ["arm1", "joint", *JOINT0, "1e", "1"], None, "not a number"),
    ("move", ["arm1", "joint", *JOINT0, "1_000", "1"], None, "not a number"),
    ("move", ["arm1", "joint", *JOINT0, "0", "-inf"], None, "unrecognized arguments: -inf"),
    ("move", ["arm1", "joint", *JOINT0, "0", "-0.5"], None, "SECONDS must be > 0"),
    ("move", ["arm1", "cart", *START, "1e999"], None, "not a finite number"),
    ("move", ["arm1", "cart", *START[:5], "2"], None, "needs 6 target values"),
    ("move", ["arm1", "joint", *JOINT0, "--", "1"], None, "needs 6 target values"),
    ("move", ["arm1", "cart", "3000", "0", "1340", "0", "180", "0", "2"], None, "unreachable"),
    ("move", ["arm1", "cart", "300", "100", "1340", "0", "180", "0", "0.001"], None, "shorter than one"),
    ("move", ["arm1", "joint", "100000", "0", "0", "0", "0", "0", "0.1"], None, "too fast"),
    ("move", ["arm1", "joint", *JOINT0, "99999999", "1"], None, "outside"),
    ("move", ["arm1", "joint", *JOINT0, "0", "1", "--timeout", "nan"], None, "not a finite number"),
    ("move", ["ARM1", "joint", *JOINT0, "0", "1"], None, "unknown subunit"),
    ("move", ["tool", "cart", *START, "2"], None, "not an arm"),
    ("home", ["arm9"], None, "unknown subunit"),
    ("home", ["tool"], None, "not an arm"),
    ("home", ["arm1", "--timeout", "inf"], None, "not a finite number"),
    ("home", ["arm1", "--timeout", "0x10"], None, "not a number"),
    ("home", ["arm1", "arm1"], None, "unrecognized arguments"),
    ("jog", ["arm1"], "j7 +10\n", "unknown axis"),
    ("jog", ["arm1"], "j6 nan\n", "not a finite number"),
    ("jog", ["arm1"], "j6 +1.5\n", "whole encoder counts"),
    ("jog", ["arm1"], "j6 99999999\n", "outside"),
    ("jog", ["arm1"], "x 1e\n", "not a number"),
    ("jog", ["arm1"], "j6 ＋１２\n", "not a number"),
    ("jog", ["arm1"], "j6\n", "expected 'AXIS DELTA'"),
    ("jog", ["arm1"], "j6 --\n", "not a number"),
    ("jog", ["arm1"], "x 5000\n", "unreachable"),
    ("jog", ["arm1", "--step", "0x10"], "", "not an integer"),
    ("jog", ["arm9"], "j1 +10\n", "unknown subunit"),
]


def _main(prog):
    from droid.tasks import home, jog, move

    return {"move": move.main, "home": home.main, "jog": jog.main}[prog]


@pytest.mark.parametrize("prog,argv,stdin,reason", LIVE,
                         ids=[f"{p} {' '.join(a)} {s or ''}".strip() for p, a, s, _ in LIVE])
def test_bad_invocation_of_a_live_cell_exits_2_and_nothing_moves(live, prog, argv, stdin, reason,
                                                                 capsys, monkeypatch):
    settled(live)
    before = arm_state(live)
    code, err = call(_main(prog), ["--cell", str(live), *argv], capsys, monkeypatch, stdin)
    assert_one_line(code, err, reason)
    after = arm_state(live)
    assert after[0] == before[0] and after[1] == before[1], "the Brain's Command record was written"
    # the held command may creep by a few counts (as encoder_pos); a written move would not
    assert np.allclose(after[2], before[2], atol=3), "encoder_cmd changed"
    assert np.allclose(after[3], before[3], atol=3), "the arm moved"
    assert after[4] == before[4], "a command id reached the controller"


# ------------------------------------------------------------------ no cell needed

OFFLINE = [  # (module, argv, reason)
    ("droid.tasks.snoop", ["arm1", "--rate", "1e"], "not a number"),
    ("droid.tasks.snoop", ["arm1", "--count", "１"], "not an integer"),
    ("droid.tasks.snoop", ["arm1", "--count", "1.5"], "not an integer"),
    ("droid.tasks.snoop", ["arm1", "mvs"], "unrecognized arguments"),
    ("droid.kinematics.cli", ["fk", "--robot", "reis_v15", *JOINT0, "nan"], "not a finite number"),
    ("droid.kinematics.cli", ["fk", "--robot", "reis_v15", *JOINT0, "0x10"], "not a number"),
    ("droid.kinematics.cli", ["fk", "--robot", "reis_v15", *JOINT0, "1e"], "not a number"),
    ("droid.kinematics.cli", ["ik", "--robot", "reis_v15", *START[:5]], "expected X Y Z A B C"),
    ("droid.kinematics.cli", ["fk", "--robot", "nosuch", *JOINT0, "0"], "nosuch"),
    ("droid.kinematics.cli", ["ik", "--robot", "reis_v15", "--prev", *JOINT0, "inf", *START], "not a finite number"),
    ("droid.brain.runtime.launcher", ["up", "--timeout", "１０"], "not a number"),
    ("droid.brain.runtime.launcher", ["down", "--timeout", "-1"], "must be > 0"),
    ("droid.brain.runtime.launcher", ["status", "--json", "extra"], "unrecognized arguments"),
    ("droid.brain.runtime.launcher", ["up", "--host", ""], "unknown host"),
    ("droid.subunits.mvs.sensor", ["--baud", "0x10"], "not an integer"),
    ("droid.subunits.mvs.sensor", ["--count", "0"], "must be > 0"),
    ("droid.subunits.mvs.sensor", ["--board-wait", "nan"], "not a finite number"),
    ("droid.subunits.mvs.sensor", ["nosuch"], "unknown subunit"),
    ("droid.brain.runtime.keys", ["--name", "x"], "required"),
    ("droid.brain.runtime.keys", ["{keys}", "--name", "a b"], "invalid key name"),
    ("droid.brain.runtime.keys", ["{keys}", "--name", "../x"], "invalid key name"),
    ("droid.brain.runtime.keys", ["{keys}", "--name", "x", "--name", "x"], "given twice"),
]


# Extreme but finite values, negative zero, huge exponents, values just outside each limit
# (issue 16): exit 2, one line naming the limit; nothing is created, nothing moves.
J6 = [*JOINT0, "0"]
EXTREME = [
    ("droid.tasks.move", ["arm1", "joint", *J6, "1e308"], "<= 3600 s"),
    ("droid.tasks.move", ["arm1", "joint", *J6, "1e9"], "<= 3600 s"),
    ("droid.tasks.move", ["arm1", "joint", *J6, "3600.001"], "<= 3600 s"),
    ("droid.tasks.move", ["arm1", "joint", *J6, "-0"], "SECONDS must be > 0"),
    ("droid.tasks.move", ["arm1", "joint", *J6, "-0.0"], "SECONDS must be > 0"),
    ("droid.tasks.move", ["arm1", "joint", *J6, "4.9e-324"], "shorter than one"),
    ("droid.tasks.move", ["arm1", "joint", *J6, "1", "--timeout", "1e308"], "<= 86400 s"),
    ("droid.tasks.move", ["arm1", "joint", *J6, "1", "--timeout", "-0"], "must be > 0"),
    ("droid.tasks.home", ["arm1", "--timeout", "86400.5"], "<= 86400 s"),
    ("droid.tasks.home", ["arm1", "--timeout", "0e0"], "must be > 0"),
    ("droid.tasks.snoop", ["arm1", "--rate", "1e308"], "<= 1000 Hz"),
    ("droid.tasks.snoop", ["arm1", "--rate", "1000.0001"], "<= 1000 Hz"),
    ("droid.tasks.snoop", ["arm1", "--rate", "-0"], ">= 0.001"),
    ("droid.tasks.snoop", ["arm1", "--rate", "1e-320"], ">= 0.001"),
    ("droid.tasks.snoop", ["arm1", "--count", "99999999999999999999999"], "<= 1000000000"),
    ("droid.tasks.jog", ["arm1", "--step", "100001"], "<= 100000 counts"),
    ("droid.tasks.jog", ["arm1", "--step", "-0"], "must be > 0"),
    ("droid.tasks.jog", ["arm1", "--step-mm", "1e300"], "<= 100 mm"),
    ("droid.tasks.jog", ["arm1", "--step-deg", "90.01"], "<= 90 deg"),
    ("droid.kinematics.cli", ["fk", "--robot", "reis_v15", *JOINT0, "1e308"], "<= 3600 deg"),
    ("droid.kinematics.cli", ["ik", "--robot", "reis_v15", "--", "300", "100", "1340", "-1e308", "90", "0"], ">= -1e+06"),
    ("droid.brain.runtime.launcher", ["up", "--timeout", "1e308"], "<= 86400 s"),
    ("droid.brain.runtime.launcher", ["down", "--timeout", "-0.0"], "must be > 0"),
    ("droid.brain.runtime.heartbeat", ["--rate", "1e308"], "<= 1000 Hz"),
    ("droid.brain.runtime.heartbeat", ["--count", "-1"], ">= 0"),
    ("droid.brain.runtime.remote", ["arm1", "--ready-fd", "99999999999999"], "<= 1048576"),
    ("droid.subunits.mvs.sensor", ["--baud", "4000001"], "outside [19200, 4000000] baud"),
    ("droid.subunits.mvs.sensor", ["--retrace-timeout", "1e308"], "<= 60 s"),
    ("droid.subunits.mvs.sensor", ["--board-wait=-1e-300"], ">= 0"),
    ("droid.subunits.gmf1.serial_prog", ["gmf1", "--baud", "9" * 40], "outside [4800, 4000000] baud"),
    ("droid.subunits.gmf1.encoder_prog", ["gmf1", "--rate", "2000.5"], "<= 2000 Hz"),
    ("droid.sim.world", ["--seed", "4294967296"], "<= 4294967295"),
    ("droid.sim.world", ["--seed", "-1"], ">= 0"),
]


@pytest.mark.parametrize("module,argv,reason", EXTREME,
                         ids=[f"{m.rsplit('.', 1)[1]} {' '.join(a)}" for m, a, _ in EXTREME])
def test_extreme_numbers_exit_2_naming_the_limit(module, argv, reason, tmp_path, cell_name, capsys,
                                                 monkeypatch):
    import importlib

    main = importlib.import_module(module).main
    if module != "droid.kinematics.cli":
        argv = argv + ["--cell", str(make_cell_file(tmp_path, cell_name))]
    code, err = call(main, argv, capsys, monkeypatch, stdin="")
    assert_one_line(code, err, reason)
    assert cell_objects(cell_name) == []  # nothing was created


@pytest.mark.parametrize("module,argv,reason", OFFLINE,
                         ids=[f"{m.rsplit('.', 1)[1]} {' '.join(a)}" for m, a, _ in OFFLINE])
def test_bad_invocation_exits_2_with_one_line(module, argv, reason, tmp_path, cell_name, capsys,
                                              monkeypatch):
    import importlib

    main = importlib.import_module(module).main
    argv = [a.replace("{keys}", str(tmp_path / "keys")) for a in argv]
    if module != "droid.kinematics.cli":
        argv += ["--cell", str(make_cell_file(tmp_path, cell_name))]
    code, err = call(main, argv, capsys, monkeypatch, stdin="")
    assert_one_line(code, err, reason)
    assert cell_objects(cell_name) == []  # nothing was created
    assert not (tmp_path / "keys").exists() or not any((tmp_path / "keys").iterdir())


def test_mvs_replay_of_a_malformed_frame_file(tmp_path, capsys, monkeypatch):
    from droid.subunits.mvs.sensor import main

    bad = tmp_path / "frames.txt"
    bad.write_text("1 2 x\n")
    code, err = call(main, ["--replay", str(bad)], capsys, monkeypatch)
    assert_one_line(code, err, "expected")

