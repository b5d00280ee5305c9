"""Force-control sweeps run as plans (issue 27 item 5; thesis §7.3): the trial's figures, a
short contact trial through droid-experiment (its CSV, figure, results table), --resume."""
from __future__ import annotations

import csv
import math
import subprocess
import sys

import pytest

from droid.experiments.contact_plan import CONTACT_FIELDS
from droid.experiments.contact_report import RESULT_COLUMNS
from droid.experiments.contact_trial import COLUMNS, ContactTrialConfig, summarize
from droid.experiments.plan import load_plan

PROG = [sys.executable, "-m", "droid.experiments.cli"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run_cli(*args, timeout=600):  # a hang guard only (docs/design.md §8: timing never decides)
    return subprocess.run(PROG + list(args), capture_output=True, text=True, timeout=timeout)


def read_results(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_summarize_takes_its_figures_from_the_rows_it_should():
    cfg = ContactTrialConfig(force_n=20.0, speed_mm_s=10.0, length_mm=2.0, settle_after_s=1.0)
    #        t,  phase,    F,   err, true, fric, depth, along, speed
    rows = [(0.0, "approach", 0.0, 20.0, 0.0, 0.0, -1.0, 0.0, 0.0),
            (0.5, "settle", 26.0, -6.0, 25.0, 0.0, 1.0, 0.0, 0.0),  # the touch's overshoot
            (1.0, "path", 23.0, -3.0, 5.0, 1.0, 1.0, 0.0, 4.0),  # the path's first second: not settled
            (2.0, "path", 21.0, -1.0, 20.0, 6.0, 1.0, 1.0, 10.0),
            (2.5, "path", 19.0, 1.0, 18.0, 6.0, 1.0, 1.5, 12.0),
            (3.0, "done", 0.0, 20.0, 0.0, 0.0, 1.0, 2.0, 0.0)]
    su = summarize(rows, cfg, "end", "2 mm done", "tX")
    assert (su.settled_cycles, su.cycles) == (2, 6)
    assert su.rms_n == pytest.approx(1.0) and su.max_n == pytest.approx(1.0) and su.max_path_n == pytest.approx(3.0)
    assert su.peak_force_n == 26.0 and su.min_true_force_n == 5.0
    assert su.mean_speed_mm_s == pytest.approx(11.0) and su.mean_true_force_n == pytest.approx(19.0)
    assert su.path_mm == 2.0 and su.stop == "end"
    none = summarize(rows[:2], cfg, "no contact", "", "tY")  # no path: NaN, not an error
    assert math.isnan(none.rms_n) and none.settled_cycles == 0


SHORT = """
name = "short"
trial = "contact"
[defaults]
length_mm = 25
[sweep]
seed = [2]
"""


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """One short contact trial (25 mm) through the console program, with its figure."""
    d = tmp_path_factory.mktemp("contact")
    plan = str(d / "short.toml")
    (d / "short.toml").write_text(SHORT)
    p = run_cli("run", "--plan", plan, "--out", str(d / "out"), "--jobs", "1")
    return plan, d / "out", p


def test_a_short_contact_trial_runs_through_droid_experiment(short_run):
    plan, out, p = short_run
    assert p.returncode == 0, p.stderr
    d = out / "short"
    (tid,) = [t.id for t in load_plan(plan).trials]
    assert sorted(f.name for f in d.iterdir()) == sorted(
        [f"{tid}.csv", f"{tid}.json", f"{tid}.png", "results.csv", "results.md"])
    with open(d / f"{tid}.csv", newline="") as f:
        log = list(csv.reader(f))
    assert tuple(log[0]) == COLUMNS and len(log) > 100
    assert (d / f"{tid}.png").read_bytes()[:8] == PNG_MAGIC
    (row,) = read_results(d / "results.csv")
    assert list(row) == ["index", "trial_id", *CONTACT_FIELDS, *RESULT_COLUMNS]
    assert row["trial_id"] == tid and row["seed"] == "2" and row["length_mm"] == "25.0"
    assert row["stop"] == "end" and row["error"] == ""
    rms = float(row["rms_n"])
    assert math.isfinite(rms) and 0.0 <= rms <= float(row["max_n"])
    assert float(row["path_mm"]) == pytest.approx(25.0, abs=1.0)
    assert float(row["min_true_force_n"]) > 0.0  # the tool stayed on the surface
    # the table's figures are the log's: recomputed from the CSV (4 decimals) they agree
    rows = [(float(r[0]), r[1], *map(float, r[2:])) for r in log[1:]]
    su = summarize(rows, ContactTrialConfig(length_mm=25.0, seed=2), "end", "")
    assert su.rms_n == pytest.approx(rms, abs=1e-3)
    assert su.mean_speed_mm_s == pytest.approx(float(row["mean_speed_mm_s"]), abs=1e-3)
    assert p.stdout.startswith(f"{tid}: normal force RMS error ") and "stop: end" in p.stdout
    md = (d / "results.md").read_text()
    assert "| index | trial | seed | RMS error [N] |" in md and f"| 0 | {tid} | 2 | {rms:.2f} |" in md


def test_resume_skips_the_finished_contact_trial(short_run):
    plan, out, p = short_run
    assert p.returncode == 0, p.stderr
    d = out / "short"
    before = {f.name: (f.stat().st_mtime_ns, f.read_bytes()) for f in d.iterdir() if f.name.startswith("t")}
    table = (d / "results.csv").read_text()
    again = run_cli("run", "--plan", plan, "--out", str(out), "--jobs", "1", "--resume")
    assert again.returncode == 0, again.stderr
    assert "short: 1 of 1 trial(s) have results; running 0" in again.stderr
    assert again.stdout == ""  # no trial ran
    assert {f.name: (f.stat().st_mtime_ns, f.read_bytes()) for f in d.iterdir() if f.name.startswith("t")} == before
    assert (d / "results.csv").read_text() == table
