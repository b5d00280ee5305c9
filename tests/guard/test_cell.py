"""The guard's bodies, its [guard] table and `droid-guard check` (issue 41; docs/guard.md)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.cli import BadInput
from droid.guard.cell import guard_scene
from droid.guard.cli import main
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T

ROOT = Path(__file__).resolve().parents[2]
SIM = ROOT / "cells" / "sim.toml"


def _cell_with_guard(tmp_path, guard: str) -> Path:
    text = SIM.read_text()
    text = text[: text.index("[guard]")] + guard
    p = tmp_path / "sim.toml"
    p.write_text(text)
    return p


def test_tool0_of_the_guards_chain_is_droid_kin_fk():
    cell = load_cell(SIM)
    scene = guard_scene(cell)
    rng = np.random.default_rng(0)
    for name, robot in (("arm1", "reis_v15"), ("gmf1", "fanuc_s400")):
        m = load_robot(robot)
        base = pose_to_T(*cell.subunits[name].base)
        q = rng.uniform(m.joint_min_deg, m.joint_max_deg, size=(20, 6))
        _, tool0 = scene.arms[name].points(np.radians(q))
        for i in range(20):
            assert np.allclose(tool0[i], base @ m.fk(q[i]), atol=1e-9)


def test_the_sim_cells_bodies_and_pairs():
    scene = guard_scene(load_cell(SIM))
    keys = {b.key for b in scene.bodies}
    assert {"arm1.link_1", "arm1.link_6", "arm1.tool", "arm1.sensor", "gmf1.workpiece", "fixture.floor"} <= keys
    pairs = {frozenset((a.key, b.key)) for a, b in scene.pairs}
    assert frozenset(("arm1.tool", "gmf1.workpiece")) not in pairs  # allowed
    assert frozenset(("arm1.link_4", "gmf1.workpiece")) in pairs
    assert frozenset(("arm1.link_2", "fixture.floor")) in pairs
    assert not any(a.owner == b.owner for a, b in scene.pairs)  # one arm's bodies are never paired


def test_check_prints_the_closest_pair(capsys):
    assert main(["check", "--cell", str(SIM), "arm1=0,0,0,0,0,0", "gmf1=0,0,0,0,0,0"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith("min ") and " mm: " in out and " with " in out
    assert main(["check", "--json", "--cell", str(SIM), "arm1=0,0,0,0,0,0", "gmf1=0,0,0,0,0,0"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["distance_mm"] > 0 and not rec["in_collision"] and rec["pairs"] > 40


def test_check_sees_a_collision(capsys, tmp_path):
    # the holder 900 mm away, both arms at zero: the Reis's torch in the Fanuc's upper arm
    text = SIM.read_text().replace("base = [2000.0, 0.0, 0.0, 180.0, 0.0, 0.0]", "base = [900.0, 0.0, 0.0, 180.0, 0.0, 0.0]")
    p = tmp_path / "near.toml"
    p.write_text(text)
    assert main(["check", "--json", "--cell", str(p), "arm1=0,0,0,0,0,0", "gmf1=0,0,0,0,0,0"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["a"] == "arm1.tool" and rec["b"] == "gmf1.link_2"
    assert rec["in_collision"] and rec["distance_mm"] < 0


@pytest.mark.parametrize("guard,words", [
    ('[guard]\nallow = [["arm9.tool", "gmf1.workpiece"]]\n', ["allow[0]", "'arm9.tool'", "no arm or fixture 'arm9'"]),
    ('[guard]\nallow = [["arm1.link_7", "gmf1.link_1"]]\n', ["allow[0]", "arm1 has no body 'link_7'"]),
    ('[guard]\nallow = [["arm1.tool"]]\n', ["allow[0]", "expected"]),
    ('[guard]\nfixtures = [{ name = "t", size_mm = [1, -1, 1] }]\n', ["fixtures[0]", "size_mm"]),
    ('[guard]\nworkpiece = { arm = "mvs", size_mm = [1, 1, 1] }\n', ["workpiece", "'mvs' is not an arm"]),
    ('[guard]\nspeed = 3\n', ["[guard] unknown key(s): speed"]),
])
def test_a_bad_guard_table_is_one_line_exit_2(tmp_path, guard, words):
    cell = _cell_with_guard(tmp_path, guard)
    with pytest.raises(BadInput) as e:
        guard_scene(load_cell(cell))
    assert all(w in str(e.value) for w in words), str(e.value)
    p = subprocess.run([sys.executable, "-c", "import sys; from droid.guard.cli import main; sys.exit(main())",
                        "check", "--cell", str(cell), "arm1=0,0,0,0,0,0", "gmf1=0,0,0,0,0,0"],
                       capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert p.returncode == 2 and p.stdout == ""
    assert len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr, p.stderr


@pytest.mark.parametrize("argv,words", [
    (["arm1=0,0,0,0,0,0"], ["no joint vector for arm(s) gmf1"]),
    (["arm1=0,0,0,0,0", "gmf1=0,0,0,0,0,0"], ["expected 6 joint angles"]),
    (["arm1=0,0,0,0,0,nan", "gmf1=0,0,0,0,0,0"], ["not a finite number"]),
    (["arm3=0,0,0,0,0,0"], ["unknown arm 'arm3'"]),
    (["arm1:0,0,0,0,0,0"], ["expected ARM=Q1"]),
])
def test_bad_joint_vectors_are_one_line(argv, words, capsys):
    assert main(["check", "--cell", str(SIM), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(w in err for w in words), err


def _near_cell(tmp_path, x_mm: float = 1300.0):
    text = SIM.read_text().replace("base = [2000.0, 0.0, 0.0, 180.0, 0.0, 0.0]", f"base = [{x_mm}, 0.0, 0.0, 180.0, 0.0, 0.0]")
    p = tmp_path / "near.toml"
    p.write_text(text)
    return load_cell(p)


def test_a_move_that_would_collide_is_refused_with_one_line(tmp_path):
    from droid.guard.refuse import check_move

    scene = guard_scene(_near_cell(tmp_path))
    still = {"gmf1": np.zeros(6)}
    # the Reis reaching forward through the Fanuc standing 1300 mm away
    line = check_move(scene, "arm1", np.array([0.0, 40.0, -30.0, 0, 0, 0]), np.array([0.0, -60.0, 40.0, 0, 0, 0]),
                      2.0, still, limit_mm=25.0)
    assert line is not None and line.startswith("would collide: arm1 ")
    assert " with gmf1 " in line and "% of the move (clearance " in line and line.endswith("mm < 25 mm)")
    pct = int(line.split(" at ")[1].split(" %")[0])
    assert 0 < pct <= 100
    # the same move turned away from the Fanuc (joint 1 at 180 deg is behind the Reis) passes
    assert check_move(scene, "arm1", np.array([150.0, 40.0, -30.0, 0, 0, 0]), np.array([150.0, -60.0, 40.0, 0, 0, 0]),
                      2.0, still, limit_mm=25.0) is None


def test_a_move_is_checked_against_the_other_arms_move(tmp_path):
    from droid.guard.refuse import check_move

    scene = guard_scene(_near_cell(tmp_path, 2000.0))
    q_from, q_to = np.array([0.0, 40.0, -30.0, 0, 0, 0]), np.array([0.0, -60.0, 40.0, 0, 0, 0])
    assert check_move(scene, "arm1", q_from, q_to, 2.0, {"gmf1": np.zeros(6)}, limit_mm=25.0) is None
    # the Fanuc is on its way toward the Reis: along its move they meet
    moving = {"gmf1": (np.array([0.0, -70.0, 50.0, 0, 0, 0]), 2.0)}
    line = check_move(scene, "arm1", q_from, q_to, 2.0, {"gmf1": np.zeros(6)}, moving, limit_mm=25.0)
    assert line is not None and "gmf1" in line, line


def test_droid_moves_check_refuses_with_exit_2_and_passes_a_clear_move(tmp_path, monkeypatch):
    from droid.tasks import guarded

    cell = _near_cell(tmp_path)
    monkeypatch.setattr(guarded, "_other_arm", lambda cell, name, gearing: (np.zeros(6), None, False))
    with pytest.raises(BadInput) as e:
        guarded.refuse_colliding_move(cell, "arm1", [0.0, 40.0, -30.0, 0, 0, 0], [0.0, -60.0, 40.0, 0, 0, 0], 2.0)
    assert str(e.value).startswith("would collide: arm1 ") and "(clearance " in str(e.value)
    assert str(e.value).endswith("< 35 mm)")  # C + Z of the default [guard] ssm terms
    guarded.refuse_colliding_move(cell, "arm1", [150.0, 40.0, -30.0, 0, 0, 0], [150.0, -60.0, 40.0, 0, 0, 0], 2.0)
    del cell.raw["guard"]  # no [guard] table: not checked
    guarded.refuse_colliding_move(cell, "arm1", [0.0, 40.0, -30.0, 0, 0, 0], [0.0, -60.0, 40.0, 0, 0, 0], 2.0)


def test_a_move_held_for_a_busy_arm_goes_once_its_move_has_cleared_the_region(tmp_path, monkeypatch):
    """Item 4, coordination: the Fanuc is on its way toward the Reis (as in the test above) for the
    first three reads, then its move is over and it stands at home: with a wait the Reis's move
    holds (one line on stderr) until the Fanuc is at rest, then passes; without a wait it is
    refused at once."""
    import io

    from droid.tasks import guarded

    cell = _near_cell(tmp_path, 2000.0)
    q_from, q_to = [0.0, 40.0, -30.0, 0, 0, 0], [0.0, -60.0, 40.0, 0, 0, 0]
    toward = np.array([0.0, -70.0, 50.0, 0, 0, 0])
    calls = []

    def fanuc(cell, name, gearing):
        calls.append(name)
        if len(calls) <= 3:  # on its move toward the Reis
            return np.zeros(6), (toward, 2.0), True
        return np.zeros(6), None, False  # its move is over (it went back home)

    monkeypatch.setattr(guarded, "_other_arm", fanuc)
    with pytest.raises(BadInput) as e:
        guarded.refuse_colliding_move(cell, "arm1", q_from, q_to, 2.0)
    assert str(e.value).startswith("would collide: arm1 ") and "gmf1" in str(e.value)
    calls.clear()
    err = io.StringIO()
    held = guarded.refuse_colliding_move(cell, "arm1", q_from, q_to, 2.0, wait_s=5.0, err=err)
    assert len(calls) == 4 and held > 0.0
    lines = err.getvalue().splitlines()
    assert len(lines) == 1 and lines[0].startswith("arm1: holding until gmf1's move clears the region (would collide: ")


def test_a_held_move_is_refused_when_the_region_does_not_clear_or_nothing_moves(tmp_path, monkeypatch):
    import io

    from droid.tasks import guarded

    cell = _near_cell(tmp_path, 2000.0)
    q_from, q_to = [0.0, 40.0, -30.0, 0, 0, 0], [0.0, -60.0, 40.0, 0, 0, 0]
    toward = np.array([0.0, -70.0, 50.0, 0, 0, 0])
    # the Fanuc stays on its way for ever: the wait ends after S seconds with the refusal
    monkeypatch.setattr(guarded, "_other_arm", lambda cell, name, gearing: (np.zeros(6), (toward, 2.0), True))
    with pytest.raises(BadInput) as e:
        guarded.refuse_colliding_move(cell, "arm1", q_from, q_to, 2.0, wait_s=0.2, err=io.StringIO())
    assert str(e.value).startswith("would collide: arm1 ") and "; the region did not clear in 0." in str(e.value)
    # an arm at rest in the way: refused at once, waiting would not clear it
    near = _near_cell(tmp_path)
    monkeypatch.setattr(guarded, "_other_arm", lambda cell, name, gearing: (np.zeros(6), None, False))
    err = io.StringIO()
    with pytest.raises(BadInput) as e:
        guarded.refuse_colliding_move(near, "arm1", q_from, q_to, 2.0, wait_s=30.0, err=err)
    assert "did not clear" not in str(e.value) and err.getvalue() == ""


def test_the_guard_imports_only_brain_kinematics_and_itself():
    """docs/design.md §7: droid.guard sits beside the Brain; never a device, a task or the simulator."""
    from tests.layering import DROID, droid_imports, within

    for path in (DROID / "guard").rglob("*.py"):
        for n in droid_imports(path):
            assert within(n, ("droid.brain", "droid.kinematics", "droid.cli", "droid.numbers", "droid.guard", "droid._guard")), (path, n)


def test_bodies_overlapping_at_home_are_refused_at_cell_up_in_one_line(tmp_path, monkeypatch):
    from droid.brain.runtime import launcher
    from droid.guard.cell import check_guard_homes

    check_guard_homes(load_cell(SIM))  # the shipped cell: clear at home
    cell = _near_cell(tmp_path, 700.0)  # the Fanuc's base 700 mm from the Reis's: their homes overlap
    with pytest.raises(BadInput) as e:
        check_guard_homes(cell)
    msg = str(e.value)
    assert "overlap at the arms' home poses" in msg and "arm1 " in msg and "gmf1 " in msg and "\n" not in msg

    def never(*a, **k):
        raise AssertionError("droid-cell up went on past the guard's check")

    monkeypatch.setattr(launcher, "up", never)
    monkeypatch.setattr(launcher, "validate_cell", lambda cell: None)
    assert launcher.main(["up", "--cell", str(cell.path)]) == 2
