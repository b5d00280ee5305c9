"""droid-experiment run/list --plan (issue 15): plans, stable IDs, results.csv, --resume, SIGINT, bad input."""
import csv
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import fields

import pytest

from droid.experiments.cli import main
from droid.experiments.plan import FIELDS, bundled_plans, load_plan
from droid.experiments.trial import TrialConfig
from tests.sim.sweep20 import NAME as SWEEP20_NAME, SWEEP20, TRIALS as SWEEP20_TRIALS

PROG = [sys.executable, "-m", "droid.experiments.cli"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run_cli(*args, timeout=600):  # a hang guard only
    return subprocess.run(PROG + list(args), capture_output=True, text=True, timeout=timeout)


def write_plan(path, text):
    path.write_text(text)
    return str(path)


SMALL = """
name = "small"
[defaults]
position = "i"
length_mm = 160
sensor = "ideal"
arm = "fast"
[sweep]
speed_mm_s = [16, 32]
delay_cycles = [0, 3]
"""


def read_results(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_bundled_plans_load_and_sweep200_has_200_trials():
    assert {"gains_delays", "sweep200"} <= set(bundled_plans())
    plan = load_plan("sweep200")
    assert len(plan.trials) == 200
    assert len({t.id for t in plan.trials}) == 200
    for name in bundled_plans():
        assert load_plan(name).trials


def test_list_prints_every_trial_with_stable_ids(tmp_path, capsys):
    plan = write_plan(tmp_path / "p.toml", SMALL)
    assert main(["list", "--plan", plan]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("# small: 4 trial(s)")
    assert len(lines) == 5
    assert "speed_mm_s=16" in lines[1] and "delay_cycles=0" in lines[1]
    assert "speed_mm_s=32" in lines[4] and "delay_cycles=3" in lines[4]  # the last key varies fastest
    ids = [ln.split()[1] for ln in lines[1:]]
    # a trial's ID depends on its parameters only: sweeping one more speed keeps the others' IDs
    more = write_plan(tmp_path / "q.toml", SMALL.replace("[16, 32]", "[16, 24, 32]"))
    again = {t.id for t in load_plan(more).trials}
    assert set(ids) <= again and len(again) == 6


@pytest.fixture(scope="module")
def small_no_figures(tmp_path_factory):
    """SMALL's directory after one run without figures (default --jobs), run once for two tests:
    the second run of the determinism check below, and (copied) the finished run in which
    test_resume_skips_trials_whose_results_exist deletes one result and resumes."""
    tmp = tmp_path_factory.mktemp("small")
    plan = write_plan(tmp / "p.toml", SMALL)
    p = run_cli("run", "--plan", plan, "--out", str(tmp / "out"), "--no-figures")
    assert p.returncode == 0, p.stderr
    return tmp / "out" / "small"


def test_plan_run_writes_trial_files_and_a_tidy_results_table(tmp_path, small_no_figures):
    plan = write_plan(tmp_path / "p.toml", SMALL)
    out = tmp_path / "out"
    p = run_cli("run", "--plan", plan, "--out", str(out), "--jobs", "2")
    assert p.returncode == 0, p.stderr
    d = out / "small"
    rows = read_results(d / "results.csv")
    assert [r["index"] for r in rows] == ["0", "1", "2", "3"]
    assert list(rows[0])[:2 + len(FIELDS)] == ["index", "trial_id", *FIELDS]
    for r in rows:
        tid = r["trial_id"]
        assert (d / f"{tid}.csv").is_file() and (d / f"{tid}.json").is_file()
        assert (d / f"{tid}.png").read_bytes()[:8] == PNG_MAGIC
        assert r["stop_reason"] == "end of seam" and r["error"] == ""
        assert 150 <= float(r["stop_s_mm"]) <= 175
        assert float(r["rms_lateral_mm"]) >= 0
        assert tid in p.stdout  # a summary line per trial
    assert {(r["speed_mm_s"], r["delay_cycles"]) for r in rows} == {("16.0", "0"), ("16.0", "3"),
                                                                       ("32.0", "0"), ("32.0", "3")}
    # the same plan again (another process, no figures, one job) gives the same table, value
    # for value (lockstep, seeded)
    assert (small_no_figures / "results.csv").read_text() == (d / "results.csv").read_text()


def test_resume_skips_trials_whose_results_exist(tmp_path, small_no_figures):
    plan = write_plan(tmp_path / "p.toml", SMALL)
    out = tmp_path / "out"
    shutil.copytree(small_no_figures, out / "small")  # a finished run of the plan (its own copy)
    d = out / "small"
    full = (d / "results.csv").read_text()
    first = read_results(d / "results.csv")[1]["trial_id"]
    os.unlink(d / f"{first}.json")
    stamp = {p.name: p.stat().st_mtime_ns for p in d.glob("*.json")}
    p = run_cli("run", "--plan", plan, "--out", str(out), "--no-figures", "--resume")
    assert p.returncode == 0, p.stderr
    assert "3 of 4 trial(s) have results; running 1" in p.stderr
    assert [ln.split(":")[0] for ln in p.stdout.splitlines()] == [first]
    assert {n: d.joinpath(n).stat().st_mtime_ns for n in stamp} == stamp  # the others untouched
    assert (d / "results.csv").read_text() == full


def test_sigint_then_resume_gives_the_uninterrupted_results(tmp_path, sweep20_reference):
    """Ctrl-C mid-sweep: exit 130, no worker left, results.csv so far; --resume completes it
    to exactly the table of one uninterrupted run (``sweep20_reference``: tests/sim/sweep20.py)."""
    plan = write_plan(tmp_path / "p.toml", SWEEP20)
    out = tmp_path / "out"
    proc = subprocess.Popen(PROG + ["run", "--plan", plan, "--out", str(out), "--no-figures", "--jobs", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    d = out / SWEEP20_NAME
    deadline = time.monotonic() + 300
    while len(list(d.glob("*.json"))) < 2 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    done = len(list(d.glob("*.json")))
    assert 2 <= done < SWEEP20_TRIALS, "the run ended before the interrupt: nothing was tested"
    partial = read_results(d / "results.csv")
    assert sum(r["error"] == "" for r in partial) == done
    p = run_cli("run", "--plan", plan, "--out", str(out), "--no-figures", "--jobs", "2", "--resume")
    assert p.returncode == 0, p.stderr
    assert f"{done} of {SWEEP20_TRIALS} trial(s) have results" in p.stderr
    assert (d / "results.csv").read_text() == sweep20_reference


def test_a_trial_that_cannot_run_exits_1_and_is_listed(tmp_path):
    plan = write_plan(tmp_path / "p.toml", """
name = "reach"
[defaults]
length_mm = 120
speed_mm_s = 32
position = "iii"
arm = "fast"
[sweep]
wrist = ["standard", "extension30"]
""")
    p = run_cli("run", "--plan", plan, "--out", str(tmp_path / "o"), "--no-figures")
    assert p.returncode == 1, p.stderr
    assert "the arm1 cannot reach the start" in p.stderr and "j5" in p.stderr and "max 135 deg" in p.stderr
    rows = read_results(tmp_path / "o" / "reach" / "results.csv")
    assert rows[0]["error"] == "" and rows[1]["error"].startswith("error: position iii: the arm1 cannot reach")


# Rows alike in shape only to other tables of bad input: each spoils its own key.
# Rows alike in shape only to other tables of bad input: each spoils its own plan key.
@pytest.mark.parametrize("body, key, value", [
    ('name = "x"\ncolour = "red"\n', "colour", '"red"'),
    ('name = "x"\n[sweep]\nspeed = [1, 2]\n', "speed", "[1, 2]"),
    ('name = "x"\n[sweep]\nspeed_mm_s = []\n', "speed_mm_s", "[]"),
    ('name = "x"\n[sweep]\nspeed_mm_s = 16\n', "speed_mm_s", "16"),
    ('name = "x"\n[sweep]\nspeed_mm_s = [16, "fast"]\n', "speed_mm_s", '"fast"'),
    ('name = "x"\n[sweep]\nspeed_mm_s = [-4]\n', "speed_mm_s", "-4"),
    ('name = "x"\n[sweep]\ndelay_cycles = [1.5]\n', "delay_cycles", "1.5"),
    ('name = "x"\n[sweep]\nseed = [true]\n', "seed", "true"),
    ('name = "x"\n[defaults]\nposition = "ix"\n', "position", '"ix"'),
    ('name = "x"\n[defaults]\nsensor = "laser"\n', "sensor", '"laser"'),
    ('name = "x"\n[defaults]\nyaw_gain = nan\n', "yaw_gain", "nan"),
    ('name = "x"\n[defaults]\nyaw_gain = 10.5\n', "yaw_gain", "10.5"),  # droid-seamtrack's ranges (issue 16)
    ('name = "x"\n[sweep]\npitch_gain = [-0.1]\n', "pitch_gain", "-0.1"),
    ('name = "x"\n[sweep]\nlength_mm = [1e308]\n', "length_mm", "1e+308"),
    ('name = "x"\n[sweep]\nspeed_mm_s = [500.5]\n', "speed_mm_s", "500.5"),
    ('name = "x"\n[sweep]\ndelay_cycles = [108001]\n', "delay_cycles", "108001"),
    ('name = "x"\n[defaults]\ndelay_at_mm = 10000.5\n', "delay_at_mm", "10000.5"),
    ('name = "x"\n[sweep]\nworkpiece = ["no_such_piece"]\n', "workpiece", '"no_such_piece"'),
    ('name = "x"\n[sweep]\nworkpiece = ["missing/piece.toml"]\n', "workpiece", '"missing/piece.toml"'),
    ('name = "x"\n[defaults]\nspeed_mm_s = 8\n[sweep]\nspeed_mm_s = [16]\n', "speed_mm_s", "[16]"),
    ('name = "x y"\n', "name", '"x y"'),
    ('name = "x"\n[sweep\n', "", ""),
])
def test_bad_plans_exit_2_with_one_line_naming_plan_key_and_value(tmp_path, capsys, body, key, value):
    assert_bad_plan(write_plan(tmp_path / "bad.toml", body), tmp_path / "out", capsys, key, value)


def assert_bad_plan(plan: str, out, capsys, key: str, value: str) -> None:
    """``run`` and ``list`` of a bad plan exit 2 with one line naming the plan, key and value;
    nothing is written (shared with tests/experiments/test_contact_plan.py)."""
    assert main(["run", "--plan", plan, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert plan in err and key in err and value in err, err
    assert not out.exists()  # nothing run, nothing written
    assert main(["list", "--plan", plan]) == 2


def test_missing_plan_and_flags_that_do_not_apply_exit_2(tmp_path, capsys):
    assert main(["run", "--plan", str(tmp_path / "nope.toml")]) == 2
    assert "plan file not found" in capsys.readouterr().err
    plan = write_plan(tmp_path / "p.toml", SMALL)
    for extra in (["--seed", "3"], ["--sensor", "camera"], ["1.1"], ["--dask", "not an address"]):
        assert main(["run", "--plan", plan, "--out", str(tmp_path / "o")] + extra) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert main(["run", "1.1", "--resume", "--out", str(tmp_path / "o")]) == 2


def test_mode_is_passed_through_or_refused(tmp_path, capsys):
    plan = write_plan(tmp_path / "p.toml", 'name = "m"\n[sweep]\nmode = ["thesis"]\n')
    if "mode" in {f.name for f in fields(TrialConfig)}:
        trial = load_plan(plan).trials[0]
        assert trial.config.mode == "thesis" and trial.params["mode"] == "thesis"
    else:
        assert main(["list", "--plan", plan]) == 2
        err = capsys.readouterr().err
        assert "mode" in err and "no tracking mode" in err and plan in err


def test_a_workpiece_path_is_relative_to_the_plan(tmp_path):
    import droid.sim.workpiece

    src = os.path.join(os.path.dirname(droid.sim.workpiece.__file__), "workpieces", "step_input.toml")
    (tmp_path / "pieces").mkdir()
    (tmp_path / "pieces" / "mine.toml").write_text(open(src).read().replace('name = "step_input"',
                                                                             'name = "mine"'))
    plan = write_plan(tmp_path / "p.toml", 'name = "w"\n[sweep]\nworkpiece = ["pieces/mine.toml"]\n')
    t = load_plan(plan).trials[0]
    assert t.params["workpiece"] == "pieces/mine.toml"
    assert t.config.workpiece == str((tmp_path / "pieces" / "mine.toml").resolve())


R25_PLAN = """
name = "r25"
[defaults]
workpiece = "ramp_r25"
position = "vii"
mode = "plus"
speed_mm_s = 16
sensor = "camera"
"""
# the experiments' default arm (full): plus mode tracks this arc to its end in every seed of the
# bench (docs/seamtrack.md, "The R25 arc")


def test_droid_experiment_tracks_the_bundled_r25_arc_to_its_end_in_plus_mode(tmp_path):
    """Issue 12's target "an arc of R25 (a workpiece with narrower surfaces) at 16 mm/s tracked
    to its end", through droid-experiment (generous margins: the seam's end, under 1 mm)."""
    plan = write_plan(tmp_path / "r25.toml", R25_PLAN)
    p = run_cli("run", "--plan", plan, "--out", str(tmp_path / "out"), "--no-figures", "--jobs", "1")
    assert p.returncode == 0, p.stderr
    (row,) = read_results(tmp_path / "out" / "r25" / "results.csv")
    assert row["stop_reason"] == "end of seam" and row["error"] == ""
    assert float(row["stop_s_mm"]) >= 300.0 + 25.0 * 3.14159 / 2 + 250.0  # past the arc, on the far straight
    assert float(row["rms_lateral_mm"]) <= 0.5 and float(row["max_lateral_mm"]) <= 1.0
