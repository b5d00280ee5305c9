"""droid-experiment end to end: short trials (hidden --length), files, summary tables, exit codes, SIGINT."""
import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from droid.experiments.cli import main
from droid.tasks.seam import report

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
PROG = [sys.executable, "-m", "droid.experiments.cli"]


def run_cli(*args, timeout=900):  # a hang guard only (docs/design.md §8: timing never decides)
    return subprocess.run(PROG + list(args), capture_output=True, text=True, timeout=timeout)


def test_one_short_trial_writes_csv_png_summary_line_and_tables(tmp_path):
    out = tmp_path / "exp"
    p = run_cli("run", "1.13", "--length", "260", "--out", str(out), "--jobs", "1", "--arm", "fast")  # the CLI's plumbing; the fast arm keeps it quick (the default full arm: test_full_arm_trial.py)
    assert p.returncode == 0, p.stderr
    d = out / "table6.1"
    assert sorted(f.name for f in d.iterdir()) == ["1.13.csv", "1.13.png", "summary.csv", "summary.md"]
    rows = report.read_csv(d / "1.13.csv")
    assert len(rows) > 100
    s = report.column(rows, "s_mm")
    assert 250 <= max(s[s == s]) <= 275  # the run length reached
    assert (d / "1.13.png").read_bytes()[:8] == PNG_MAGIC
    lines = p.stdout.splitlines()
    assert len(lines) == 1 and lines[0].startswith("1.13: tool lateral RMS") and "mm" in lines[0]
    with open(d / "summary.csv", newline="") as f:
        (rec,) = list(csv.DictReader(f))
    assert rec["id"] == "1.13" and rec["speed_mm_s"] == "16" and rec["position"] == "iii"
    assert rec["stop_reason"] == "end of seam" and rec["seam_lost"] == "no"
    su = report.summarize(rows)
    assert float(rec["rms_lateral_mm"]) == pytest.approx(su.rms_lateral_mm, abs=1e-3)
    assert "| 1.13 | step input | 16 | iii |" in (d / "summary.md").read_text()


def test_exp4_writes_the_standard_deviations_across_its_runs(tmp_path):
    out = tmp_path / "exp"
    p = run_cli("run", "exp4", "--length", "200", "--out", str(out), "--jobs", "2", "--no-figures", "--seed", "5",
                "--arm", "fast")
    assert p.returncode == 0, p.stderr
    d = out / "exp4"
    assert sorted(f.name for f in d.iterdir()) == ["4.1.csv", "4.2.csv", "4.3.csv", "4.4.csv", "std.csv",
                                                   "summary.csv", "summary.md"]
    assert sorted(line.split(":")[0] for line in p.stdout.splitlines()) == ["4.1", "4.2", "4.3", "4.4"]
    with open(d / "std.csv", newline="") as f:
        recs = list(csv.DictReader(f))
    assert list(recs[0]) == ["s_mm", "std_lead_lateral_mm", "std_tool_lateral_mm", "std_lead_depth_mm",
                             "std_tool_depth_mm"]
    assert len(recs) > 50
    lead = [float(r["std_lead_lateral_mm"]) for r in recs]
    assert all(v >= 0 for v in lead) and max(lead) > 0  # the seeds differ: the camera noise differs
    seeds = [r["seed"] for r in csv.DictReader(open(d / "summary.csv", newline=""))]
    assert len(set(seeds)) == 4


@pytest.mark.parametrize("argv, message", [
    (["run", "7.1"], "unknown experiment '7.1'"),
    (["run"], "required"),
    (["run", "1.1", "--jobs", "0"], "--jobs"),
    (["run", "1.1", "--sensor", "laser"], "--sensor"),
    (["run", "1.1", "--mode", "fastest"], "--mode"),
    (["run", "1.1", "--seed", "-3"], "--seed"),
    (["run", "1.1", "--length", "nan"], "--length"),
    (["fly"], "invalid choice"),
    ([], "required"),
])
def test_bad_arguments_exit_2_with_one_line(argv, message, capsys, tmp_path):
    if argv[:1] == ["run"]:
        argv = argv + ["--out", str(tmp_path / "out")]
    assert _exit_code(lambda: main(argv)) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert not list(tmp_path.iterdir())  # nothing run, nothing written


def _exit_code(fn):
    """main's return value, or the code of argparse's SystemExit."""
    try:
        return fn()
    except SystemExit as exc:
        return exc.code


def test_list_prints_one_line_per_experiment(capsys):
    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 41 + 5 + 28 + 4 + 1
    assert lines[0].startswith("1.1 ") and "4 mm/s" in lines[0] and lines[-1].startswith("5.1 ")
    assert main(["list", "3.9"]) == 0
    assert "Kp yaw 0.55, pitch 0.15" in capsys.readouterr().out


@pytest.mark.integration
def test_realtime_runs_the_trial_on_a_cell_of_processes(tmp_path):
    """--realtime: a cell of its own is brought up, both arms homed, droid-seamtrack run,
    the cell brought down (the leak fixture checks); the same files as in lockstep.
    (1.12: 8 mm/s.  In plus mode, which holds the commanded speed: the thesis's tracker covers
    170 mm at about 3 mm/s, so its run here took a minute of real time more; it is tracked on the
    real-time cell by tests/tasks/test_seamtrack_cell.py over 220 mm.)"""
    out = tmp_path / "rt"
    p = run_cli("run", "1.12", "--realtime", "--mode", "plus", "--length", "170", "--out", str(out),
                "--seed", "4")
    assert p.returncode == 0, p.stderr
    line = p.stdout.strip().splitlines()[-1]
    assert line.startswith("1.12: tool lateral RMS") and "seam not lost" in line and "end of seam" in line
    rows = report.read_csv(out / "table6.1" / "1.12.csv")
    s = report.column(rows, "s_mm")
    assert 160 <= np.nanmax(s) <= 180
    assert (out / "table6.1" / "1.12.png").read_bytes()[:4] == b"\x89PNG"
    assert "1.12" in (out / "table6.1" / "summary.md").read_text()


def _session_pids(sid):
    pids = []
    for name in os.listdir("/proc"):
        if name.isdigit():
            try:
                stat = Path(f"/proc/{name}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(stat[3]) == sid and stat[0] != "Z":
                pids.append(int(name))
    return pids


def test_sigint_stops_the_pool_and_exits_130(tmp_path):
    # Ctrl-C goes to the whole foreground process group: send SIGINT to the session's group.
    p = subprocess.Popen(PROG + ["run", "1.1", "1.2", "1.6", "--out", str(tmp_path), "--jobs", "2", "--no-figures", "--arm", "fast"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 300  # hang guards only
        while len(_session_pids(p.pid)) < 3 and time.monotonic() < deadline:  # parent + 2 workers
            time.sleep(0.05)
        assert len(_session_pids(p.pid)) >= 3, "the pool did not start"
        os.killpg(p.pid, signal.SIGINT)
        _, err = p.communicate(timeout=300)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    assert p.returncode == 130, err
    assert "Traceback" not in err
    assert _session_pids(p.pid) == []  # no worker left running
