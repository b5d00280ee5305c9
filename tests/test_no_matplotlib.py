"""Without matplotlib every figure path ends with one line naming it -- never a traceback (issue 15)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from droid.cli import run

ROOT = Path(__file__).resolve().parents[1]


def _blocked_env(tmp_path) -> dict:
    block = tmp_path / "block" / "matplotlib"
    block.mkdir(parents=True)
    (block / "__init__.py").write_text(
        "raise ModuleNotFoundError(\"No module named 'matplotlib'\", name='matplotlib')\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path / "block"), str(ROOT)])}


def test_droid_experiment_runs_without_matplotlib_and_says_so_once(tmp_path):
    # The figure paths (each trial's, then exp4's std.png) are the same whichever arm model ran
    # the trials: the fast arm keeps this quick (the default full arm homes before each trial;
    # it has its own tests in tests/sim/test_full_arm_trial.py).
    env = _blocked_env(tmp_path)
    plan = tmp_path / "p.toml"
    plan.write_text('name = "n"\n[defaults]\nlength_mm = 120\narm = "fast"\n[sweep]\nspeed_mm_s = [16, 32]\n')
    p = subprocess.run([sys.executable, "-m", "droid.experiments.cli", "run", "--plan", str(plan), "--out",
                        str(tmp_path / "o"), "--jobs", "2"], capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    assert p.stderr.count("no figures: matplotlib is not installed (pip install matplotlib)") == 1
    d = tmp_path / "o" / "n"
    assert len(list(d.glob("*.csv"))) == 3 and not list(d.glob("*.png"))  # 2 logs + results.csv
    p = subprocess.run([sys.executable, "-m", "droid.experiments.cli", "run", "exp4", "--length", "170",
                        "--arm", "fast", "--out", str(tmp_path / "e"), "--jobs", "2"], capture_output=True, text=True,
                       env=env, timeout=300)
    assert p.returncode == 0 and "Traceback" not in p.stderr
    assert "exp4: no figures: matplotlib is not installed" in p.stderr
    assert (tmp_path / "e" / "exp4" / "std.csv").is_file() and not (tmp_path / "e" / "exp4" / "std.png").exists()


def test_every_program_ends_a_missing_matplotlib_with_one_line(capsys):
    @run
    def main(argv=None):
        raise ModuleNotFoundError("No module named 'matplotlib.figure'", name="matplotlib.figure")

    assert main([]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "matplotlib is not installed (pip install matplotlib)" in err[0]


def test_other_missing_modules_still_raise():
    @run
    def main(argv=None):
        raise ModuleNotFoundError("No module named 'nonesuch'", name="nonesuch")

    try:
        main([])
    except ModuleNotFoundError:
        return
    raise AssertionError("a missing core module must not be hidden")
