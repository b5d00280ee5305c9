"""Plans of the force-control trial (issue 27 item 5: "the same cycle runs in lockstep (a trial
type of droid-experiment), so force-control sweeps run as plans"): the ``trial = "contact"``
key, its keys and their checks (one line, exit 2), stable IDs, the bundled plan."""
from __future__ import annotations

import subprocess
import sys

import pytest

from droid.experiments.cli import main
from droid.experiments.contact_plan import CONTACT_FIELDS
from droid.experiments.contact_trial import ContactTrialConfig
from droid.experiments.plan import load_plan, trial_id
from tests.sim.test_experiment_plan import assert_bad_plan

PROG = [sys.executable, "-m", "droid.experiments.cli"]


def run_cli(*args, timeout=600):  # a hang guard only (docs/design.md §8: timing never decides)
    return subprocess.run(PROG + list(args), capture_output=True, text=True, timeout=timeout)


def write_plan(path, text):
    path.write_text(text)
    return str(path)


def test_the_bundled_plan_is_the_issues_measure_ten_seeds():
    plan = load_plan("contact_seeds")
    assert plan.trial == "contact" and plan.fields == CONTACT_FIELDS
    assert [t.params["seed"] for t in plan.trials] == list(range(1, 11))
    for t in plan.trials:
        assert t.kind == "contact" and t.id == trial_id(t.params)
        c = t.config
        assert isinstance(c, ContactTrialConfig)
        assert (c.force_n, c.speed_mm_s, c.length_mm, c.seed) == (20.0, 10.0, 200.0, t.params["seed"])
        # the rest as `python -m droid.experiments.contact_trial SEED` runs it (docs/contact.md's table)
        assert c == ContactTrialConfig(seed=c.seed, workpiece="step_input")
    assert len({t.id for t in plan.trials}) == 10


def test_list_shows_contact_trials_and_ids_depend_on_parameters_only(tmp_path, capsys):
    body = 'name = "c"\ntrial = "contact"\n[defaults]\nlength_mm = 30\n[sweep]\nforce_n = [10, 20]\n'
    assert main(["list", "--plan", write_plan(tmp_path / "c.toml", body)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "# c: 2 contact trial(s)"
    assert "force_n=10 speed_mm_s=10 length_mm=30 seed=1 workpiece=step_input" in lines[1]
    more = load_plan(write_plan(tmp_path / "d.toml", body.replace("[10, 20]", "[10, 15, 20]")))
    assert {ln.split()[1] for ln in lines[1:]} <= {t.id for t in more.trials}
    # a seam plan's default trial is unchanged: trial = "seamtrack" written out gives the same trials
    seam = 'name = "s"\n[sweep]\nspeed_mm_s = [16, 32]\n'
    a = load_plan(write_plan(tmp_path / "s1.toml", seam))
    b = load_plan(write_plan(tmp_path / "s2.toml", 'trial = "seamtrack"\n' + seam))
    assert a.trial == b.trial == "seamtrack" and a.trials == b.trials


def test_a_gains_file_is_relative_to_the_plan_and_bounds_the_force(tmp_path, capsys):
    (tmp_path / "g").mkdir()
    (tmp_path / "g" / "soft.toml").write_text("force_max_n = 15.0\napproach_max_mm = 8.0\n")
    ok = write_plan(tmp_path / "ok.toml",
                    'name = "g"\ntrial = "contact"\n[defaults]\ngains = "g/soft.toml"\nforce_n = 12\n')
    (t,) = load_plan(ok).trials
    assert t.params["gains"] == "g/soft.toml"
    assert t.config.gains == str((tmp_path / "g" / "soft.toml").resolve())
    bad = write_plan(tmp_path / "bad.toml", 'name = "g"\ntrial = "contact"\n[defaults]\ngains = "g/soft.toml"\n')
    assert main(["list", "--plan", bad]) == 2  # the default 20 N is past this file's force_max_n
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "force_n = 20" in err and "force_max_n 15 N" in err and bad in err


@pytest.mark.parametrize("body, key, value", [
    ('trial = "force"\n', "trial", '"force"'),
    ('trial = "contact"\n[defaults]\nyaw_gain = 0.2\n', "yaw_gain", "0.2"),  # a seam key in a contact plan
    ('trial = "contact"\n[sweep]\ndelay_cycles = [1, 2]\n', "delay_cycles", "[1, 2]"),
    ('trial = "contact"\n[defaults]\ntorque = 3\n', "torque", "3"),
    ('[defaults]\nforce_n = 20\n', "force_n", "20"),  # a contact key in a seam plan
    ('trial = "contact"\n[sweep]\nforce_n = [20, 70]\n', "force_n", "70"),  # past force_max_n 60 N
    ('trial = "contact"\n[sweep]\nforce_n = [-1]\n', "force_n", "-1"),
    ('trial = "contact"\n[defaults]\nforce_n = "hard"\n', "force_n", '"hard"'),
    ('trial = "contact"\n[sweep]\nspeed_mm_s = [600]\n', "speed_mm_s", "600"),
    ('trial = "contact"\n[sweep]\nspeed_mm_s = [0]\n', "speed_mm_s", "0"),
    ('trial = "contact"\n[defaults]\nlength_mm = 10001\n', "length_mm", "10001"),
    ('trial = "contact"\n[defaults]\nseed = 1.5\n', "seed", "1.5"),
    ('trial = "contact"\n[defaults]\nseed = -3\n', "seed", "-3"),
    ('trial = "contact"\n[defaults]\nlateral_mm = 25\n', "lateral_mm", "25"),  # the upper plate
    ('trial = "contact"\n[defaults]\nlateral_mm = -80\n', "lateral_mm", "-80"),  # beside the workpiece
    ('trial = "contact"\n[defaults]\nclearance_mm = -1\n', "clearance_mm", "-1"),
    ('trial = "contact"\n[defaults]\nclearance_mm = 30\n', "clearance_mm", "30"),  # approach_max_mm
    ('trial = "contact"\n[defaults]\nworkpiece = "helix_r300"\n', "workpiece", '"helix_r300"'),  # no [contact]
    ('trial = "contact"\n[defaults]\nworkpiece = "nope"\n', "workpiece", '"nope"'),
    ('trial = "contact"\n[defaults]\nposition = "ix"\n', "position", '"ix"'),
    ('trial = "contact"\n[defaults]\ngains = "missing.toml"\n', "gains", '"missing.toml"'),
    ('trial = "contact"\n[defaults]\ngains = 3\n', "gains", "3"),
])
def test_bad_contact_plans_exit_2_with_one_line_naming_plan_key_and_value(tmp_path, capsys, body, key, value):
    assert_bad_plan(write_plan(tmp_path / "bad.toml", 'name = "x"\n' + body), tmp_path / "out", capsys, key, value)


def test_a_3d_workpiece_with_contact_is_refused_by_the_force_trial(tmp_path, capsys):
    """The world takes contact on a 3-D workpiece; the trial's start and path are the plane's."""
    (tmp_path / "climb.toml").write_text('[[segment]]\ntype = "line"\nlength_mm = 300\nrise_mm = 20\n[contact]\n')
    plan = write_plan(tmp_path / "p.toml", 'name = "x"\ntrial = "contact"\n[defaults]\nworkpiece = "climb.toml"\n')
    assert_bad_plan(plan, tmp_path / "out", capsys, "workpiece", '"climb.toml"')
    assert "is a 3-D workpiece" in capsys.readouterr().err  # the line of `list`, after assert_bad_plan's `run`


def test_a_bad_gains_file_is_one_line_too(tmp_path, capsys):
    (tmp_path / "unstable.toml").write_text("admittance_mm_per_n_s = 3.0\n")  # K k T = 2
    plan = write_plan(tmp_path / "p.toml", 'name = "x"\ntrial = "contact"\n[defaults]\ngains = "unstable.toml"\n')
    assert main(["list", "--plan", plan]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "gains" in err and "unstable at K k T >= 2" in err and plan in err


def test_the_console_program_exits_2_without_a_traceback(tmp_path):
    plan = write_plan(tmp_path / "p.toml", 'name = "x"\ntrial = "contact"\n[defaults]\npitch_gain = 0.1\n')
    p = run_cli("run", "--plan", plan, "--out", str(tmp_path / "o"))
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.strip().splitlines() == [
        f"droid-experiment: plan {plan}: [defaults] pitch_gain = 0.1: a seam-tracking key, not one of a contact plan "
        f"(its keys: {', '.join(CONTACT_FIELDS)})"]
