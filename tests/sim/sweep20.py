"""The 20-trial plan that the interrupt tests stop with SIGINT and --resume, and its reference
table: one uninterrupted run on the process pool, shared by test_experiment_plan.py (Ctrl-C on
the pool) and test_experiment_dask.py (Ctrl-C on a local Dask cluster) -- each compares its
resumed table with the same pool run, so it is run once per session (tests/sim/conftest.py)."""
import subprocess
import sys

PROG = [sys.executable, "-m", "droid.experiments.cli"]

# 20 trials, ~0.5 s each (the camera sensor): long enough that an interrupt lands mid-run
SWEEP20 = """
name = "sweep20"
[defaults]
position = "i"
length_mm = 160
sensor = "camera"
arm = "fast"
[sweep]
speed_mm_s = [8, 12, 16, 24, 32]
delay_cycles = [0, 1, 2, 3]
"""
NAME = "sweep20"
TRIALS = 20


def pool_reference(tmp) -> str:
    """results.csv of one uninterrupted run of SWEEP20 on the pool (--jobs 2), run in ``tmp``."""
    plan = tmp / "sweep20.toml"
    plan.write_text(SWEEP20)
    ref = subprocess.run(PROG + ["run", "--plan", str(plan), "--out", str(tmp / "ref"), "--no-figures",
                                 "--jobs", "2"], capture_output=True, text=True, timeout=600)  # a hang guard only
    assert ref.returncode == 0, ref.stderr
    return (tmp / "ref" / NAME / "results.csv").read_text()
