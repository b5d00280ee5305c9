"""droid-kin: the command-line contract (docs/design.md §6) — output forms, stdin mode, exit codes."""
from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from droid.kinematics import load_robot
from droid.kinematics.cli import main
from droid.kinematics.transforms import pose_to_T

ROOT = Path(__file__).resolve().parents[2]
START = ["300", "100", "1340", "0", "180", "0"]


def run_cli(*args, stdin: str | None = None):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run(
        [sys.executable, "-m", "droid.kinematics.cli", *args],
        input=stdin,
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )


# ---------------------------------------------------------------- subprocess


def test_subprocess_fk_ik_json_and_exit_codes():
    r = run_cli("fk", "--robot", "reis_v15", "--json", "10", "20", "-30", "40", "50", "60")
    assert r.returncode == 0, r.stderr
    t = np.array(json.loads(r.stdout)["T"])
    assert np.allclose(t, load_robot("reis_v15").fk([10, 20, -30, 40, 50, 60]), atol=1e-12)

    r = run_cli("ik", "--robot", "reis_v15", "--json", *START)
    assert r.returncode == 0, r.stderr
    rec = json.loads(r.stdout)
    assert len(rec["solutions"]) == 8 and all(len(s) == 6 for s in rec["solutions"])
    assert np.allclose(load_robot("reis_v15").fk(rec["pick"]), pose_to_T(*map(float, START)), atol=1e-7)

    r = run_cli("ik", "--robot", "reis_v15", "3000", "0", "0", "0", "0", "0")
    assert r.returncode == 2 and r.stdout == ""
    assert len(r.stderr.strip().splitlines()) == 1 and "out of reach" in r.stderr


def test_subprocess_stdin_stream_thousands_of_poses():
    reis = load_robot("reis_v15")
    rng = np.random.default_rng(8)
    q = rng.uniform(reis.joint_min_deg * 0.9, reis.joint_max_deg * 0.9, (2000, 6))
    text = "\n".join(" ".join(repr(v) for v in row) for row in q.tolist()) + "\n"
    r = run_cli("fk", "--robot", "reis_v15", "--json", stdin=text)
    assert r.returncode == 0, r.stderr
    ts = np.array([json.loads(line)["T"] for line in r.stdout.splitlines()])
    assert ts.shape == (2000, 4, 4)
    assert np.allclose(ts, reis.fk_batch(q), atol=1e-12)
    # feed the poses to ik (chained previous pick), compare with the library's pick
    from droid.kinematics.transforms import T_to_pose

    poses = T_to_pose(ts)
    text = "\n".join(" ".join(repr(v) for v in row) for row in poses.tolist()) + "\n"
    r = run_cli("ik", "--robot", "reis_v15", "--json", stdin=text)
    lines = r.stdout.splitlines()
    assert len(lines) == 2000
    prev = np.zeros(6)
    for pose, line in zip(poses, lines):
        rec = json.loads(line)
        try:
            expect = reis.ik(pose_to_T(*pose), prev)
        except ValueError:
            assert rec["pick"] is None and "error" in rec
            continue
        assert np.allclose(rec["pick"], expect, atol=1e-9)
        prev = expect
    assert r.returncode == (2 if any("error" in json.loads(x) for x in lines) else 0)


# ---------------------------------------------------------------- in process


def test_fk_plain_prints_a_pose(capsys):
    assert main(["fk", "--robot", "reis_v15", "0", "0", "0", "0", "0", "0"]) == 0
    out = capsys.readouterr().out.split()
    assert np.allclose([float(v) for v in out], [540, 0, 1325, 0, 90, 180], atol=1e-6)


def test_ik_plain_pick_and_all(capsys):
    assert main(["ik", "--robot", "reis_v15", *START]) == 0
    pick = [float(v) for v in capsys.readouterr().out.split()]
    assert len(pick) == 6
    assert main(["ik", "--robot", "reis_v15", "--all", *START]) == 0
    line = capsys.readouterr().out.strip()
    parts = line.split(" | ")
    assert len(parts) == 9 and parts[0].startswith("pick: ") and parts[1].startswith("0: ")
    assert np.allclose([float(v) for v in parts[0][6:].split()], pick)


def test_ik_prev_selects_the_branch(capsys):
    reis = load_robot("reis_v15")
    sols = reis.ik_all(pose_to_T(*map(float, START)))
    prev = sols[0]
    assert main(["ik", "--robot", "reis_v15", "--json", "--prev", *map(str, prev), *START]) == 0
    assert np.allclose(json.loads(capsys.readouterr().out)["pick"], sols[0], atol=1e-6)


def test_robot_from_a_path(capsys, tmp_path):
    from droid.kinematics.robots import BUNDLED_DIR

    path = tmp_path / "my_arm.toml"
    path.write_text((BUNDLED_DIR / "fanuc_s400.toml").read_text())
    assert main(["fk", "--robot", str(path), "0", "0", "0", "0", "0", "0"]) == 0
    assert np.allclose([float(v) for v in capsys.readouterr().out.split()][:3], [1200, 0, 1900])


@pytest.mark.parametrize(
    "argv",
    [
        ["ik", "--robot", "reis_v15", "3000", "0", "0", "0", "0", "0"],  # out of reach
        ["ik", "--robot", "reis_v15", "-900", "0", "300", "0", "90", "0"],  # outside the joint limits
        ["ik", "--robot", "nope", *START],  # unknown robot
        ["ik", "--robot", "reis_v15", "1", "2", "3"],  # wrong arity
        ["fk", "--robot", "reis_v15", "1", "2", "3", "4", "5", "6", "7"],
        ["ik", "--robot", "reis_v15", "--prev", "1", "2", *START],  # --prev eats the pose: 2 left
    ],
)
def test_bad_input_exit_2_one_line(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "argv",
    [
        ["ik", "--robot", "reis_v15", "nan", "0", "0", "0", "0", "0"],
        ["ik", "--robot", "reis_v15", "inf", "0", "0", "0", "0", "0"],
        ["fk", "--robot", "reis_v15", "1", "2", "x", "4", "5", "6"],
        ["fk", "1", "2", "3", "4", "5", "6"],  # --robot missing
        ["spin"],
    ],
)
def test_argument_errors_exit_2_one_line(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_json_unreachable_prints_the_record_and_exits_2(capsys):
    assert main(["ik", "--robot", "reis_v15", "--json", "-900", "0", "300", "0", "90", "0"]) == 2
    rec = json.loads(capsys.readouterr().out)
    assert rec["pick"] is None and "limits" in rec["error"]
    assert any(s is not None for s in rec["solutions"])


def test_stdin_mode_reports_bad_lines_and_continues(capsys, monkeypatch):
    text = "\n".join(
        [
            "300 100 1340 0 180 0",
            "# a comment",
            "",
            "300, 120, 1340, 0, 180, 0",
            "1 2 3",
            "300 100 nan 0 180 0",
            "3000 0 0 0 0 0",
            "300 100 1340 0 180 0 " + " ".join(["0"] * 6),
        ]
    )
    monkeypatch.setattr(sys, "stdin", io.StringIO(text))
    assert main(["ik", "--robot", "reis_v15"]) == 2
    cap = capsys.readouterr()
    out = cap.out.splitlines()
    assert len(out) == 6  # one per non-blank, non-comment line
    assert len([float(v) for v in out[0].split()]) == 6
    assert len([float(v) for v in out[1].split()]) == 6
    assert out[2] == "error: line 5: expected 6 or 12 numbers, got 3"
    assert out[3].startswith("error: line 6: not a finite number")
    assert out[4].startswith("error: line 7: target out of reach")
    assert len(out[5].split()) == 6
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and "3 input line(s) failed; first: line 5" in err[0]


def test_stdin_mode_chains_the_previous_pick(capsys, monkeypatch):
    reis = load_robot("reis_v15")
    # start near the flipped-wrist solution: later poses must stay on that branch
    first = pose_to_T(*map(float, START))
    flipped = reis.ik_all(first)[0]
    poses = [[300.0 + 5 * i, 100.0, 1340.0, 0.0, 180.0, 0.0] for i in range(20)]
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n".join(" ".join(map(str, p)) for p in poses)))
    assert main(["ik", "--robot", "reis_v15", "--json", "--prev", *map(str, flipped)]) == 0
    picks = [json.loads(x)["pick"] for x in capsys.readouterr().out.splitlines()]
    prev = flipped
    for p, got in zip(poses, picks):
        expect = reis.ik(pose_to_T(*p), prev)
        assert np.allclose(got, expect, atol=1e-9)
        prev = expect
    assert all(q[4] > 0 for q in picks)  # stayed on wrist branch 0


def test_stdin_fk_plain(capsys, monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO("0 0 0 0 0 0\n0 0 0 0 0\n"))
    assert main(["fk", "--robot", "reis_v15"]) == 2
    out = capsys.readouterr().out.splitlines()
    assert np.allclose([float(v) for v in out[0].split()], [540, 0, 1325, 0, 90, 180], atol=1e-6)
    assert out[1] == "error: line 2: expected 6 numbers, got 5"


def test_stdin_singular_pose_uses_the_chained_hint(capsys, monkeypatch):
    """At the wrist singularity the batched path re-solves with the actual previous pick (same as the library)."""
    reis = load_robot("reis_v15")
    q_sing = np.array([10.0, 5.0, 20.0, 30.0, 0.0, 40.0])
    from droid.kinematics.transforms import T_to_pose

    pose_a = T_to_pose(reis.fk([10.0, 5.0, 20.0, 70.0, 30.0, 40.0]))
    pose_b = T_to_pose(reis.fk(q_sing))
    text = " ".join(map(repr, pose_a.tolist())) + "\n" + " ".join(map(repr, pose_b.tolist())) + "\n"
    monkeypatch.setattr(sys, "stdin", io.StringIO(text))
    assert main(["ik", "--robot", "reis_v15", "--json"]) == 0
    picks = [json.loads(x)["pick"] for x in capsys.readouterr().out.splitlines()]
    expect_a = reis.ik(pose_to_T(*pose_a), np.zeros(6))
    expect_b = reis.ik(pose_to_T(*pose_b), expect_a)
    assert np.allclose(picks[0], expect_a, atol=1e-9)
    assert np.allclose(picks[1], expect_b, atol=1e-9)
    assert picks[1][3] == pytest.approx(expect_a[3])  # joint 4 kept from the previous pick


def test_robots_listing(capsys):
    assert main(["robots", "--json"]) == 0
    recs = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert {r["name"] for r in recs} >= {"reis_v15", "fanuc_s400"}
    assert [r["assumed"] for r in recs if r["name"] == "fanuc_s400"] == [True]


def test_stdin_numbers_are_held_to_the_command_line_ranges(capsys, monkeypatch):
    """A stdin line is checked as the same numbers on the command line are (issue 16):
    joint angles in [-3600, 3600] deg, pose values in [-1e6, 1e6]; -0 is zero."""
    monkeypatch.setattr(sys, "stdin", io.StringIO("0 0 0 0 0 1e308\n0 0 0 0 0 -3600.0000000000005\n"
                                                  "0 0 0 0 0 -0\n0 0 0 0 0 5e-324\n"))
    assert main(["fk", "--robot", "reis_v15"]) == 2
    cap = capsys.readouterr()
    out = cap.out.splitlines()
    assert out[0] == "error: line 1: must be >= -3600 and <= 3600 deg: '1e308' is outside [-3600, 3600] deg"
    assert out[1].startswith("error: line 2: must be >= -3600") and len(out) == 4
    assert np.allclose([float(v) for v in out[2].split()], [540, 0, 1325, 0, 90, 180], atol=1e-6)
    assert "2 input line(s) failed" in cap.err and len(cap.err.strip().splitlines()) == 1
    monkeypatch.setattr(sys, "stdin", io.StringIO("300 100 1340 0 90 -1e308\n300 100 1340 0 180 0 0 0 0 0 0 4000\n"))
    assert main(["ik", "--robot", "reis_v15"]) == 2
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("error: line 1: must be >= -1e+06") and "'-1e308'" in out[0]
    assert out[1] == "error: line 2: must be >= -3600 and <= 3600 deg: '4000' is outside [-3600, 3600] deg"
