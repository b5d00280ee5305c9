"""droid-seamtrack on the real-time process cell (issue 7; thesis §5.5, §6.1).

The tests on a cell share one with other modules' tests, brought up and homed once for the
session (tests/conftest.py ``shared_sim_cell``: homing costs about 30 s a cell); each checks it
whole before it starts (``homed_sim_cell``).  Their order leaves each fit for the next: "seam
lost" runs first of every test on the shared cell (marked ``shared_cell_first``), while the
holder is still at home; the tracking runs move both arms to their start themselves; the servo
fault runs last of all (``shared_cell_last``), as it breaks the cell.  The cell is brought down
after the session and the leak checks prove nothing stays.  No timing decides a verdict: waits are generous polls, and the
tracking tolerances are stated below.
"""
from __future__ import annotations

import csv
import json
import math
import os
import select
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from droid.kinematics.transforms import T_to_pose
from droid.brain.cell.cell_layout import load_layout
from droid.tasks.seam.report import COLUMNS
from tests.brain.cellutil import ROOT, cell_status, droid, reaped, wait_for

pytestmark = pytest.mark.integration
SEAMTRACK = "droid.tasks.seamtrack"
SNOOP = "droid.tasks.snoop"
#: Stated tolerance of an 8 mm/s run over the step-input seam from position (i): RMS tool
#: error after settling (s > 150 mm) [mm].  (8 mm/s: at 16 mm/s the real-time loop is
#: stable on a quiet host but oscillates when the host is loaded -- docs/safety.md.)
RT_RMS_LATERAL_MM = 4.0
RT_RMS_DEPTH_MM = 3.0
#: Real time vs lockstep (the ``full`` arm model: every Reis core and the plant): mean
#: |difference| of the tool's lateral and depth error at the same tool travel, after
#: settling [mm].  Measured: 0.37 and 0.13 mm.
AGREE_MEAN_MM = 1.0


def run(*args, cell, timeout=120):
    return droid(SEAMTRACK, *args, "--cell", str(cell), timeout=timeout)


def snoop(cell, sub):
    out = droid(SNOOP, sub, "--json", "--count", "1", "--rate", "50", "--cell", str(cell))
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def read_log(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == COLUMNS
    return {name: np.array([float(r[i]) if r[i] not in ("",) and name not in ("phase", "delay_state")
                            else math.nan for r in rows[1:]]) for i, name in enumerate(COLUMNS)}


def assert_standing(cell, arm="arm1"):
    """No command is in progress and the servo's command does not change any more."""
    a = snoop(cell, arm)
    time.sleep(0.3)
    b = snoop(cell, arm)
    assert a["busy"] == 0 and b["busy"] == 0
    assert a["encoder_cmd"] == b["encoder_cmd"], (a, b)
    assert not set(b["fault"]) & {"servo", "watchdog", "following"}, b


def assert_agrees_with_lockstep(d, travel, settled, ls, bound_mm: float = AGREE_MEAN_MM) -> None:
    """The real-time log ``d`` and the lockstep trial ``ls`` agree after settling: mean |difference|
    of the tool's lateral and depth error at the same tool travel <= ``bound_mm``."""
    ls_travel = ls.column("travel_mm")
    for name in ("tool_lateral_mm", "tool_depth_mm"):
        ref = np.interp(travel[settled], ls_travel, ls.column(name))
        diff = np.abs(d[name][settled] - ref)
        assert float(np.nanmean(diff)) <= bound_mm, (name, float(np.nanmean(diff)))


@pytest.mark.shared_cell_first
def test_seam_lost_when_the_sensor_sees_no_seam(homed_sim_cell, tmp_path):
    """The holder stays at home, so the workpiece is nowhere near the sensor: after the
    dead zone the lead sensor is invalid, and the run stops as 'seam lost' (exit 1)."""
    T_reis, _ = load_layout().start_poses("i")
    out = droid("droid.tasks.move", "--cell", str(homed_sim_cell), "arm1", "cart", "--",
                *[f"{v:.6f}" for v in T_to_pose(T_reis)], "3", timeout=60)
    assert out.returncode == 0, out.stderr
    before = snoop(homed_sim_cell, "arm1")
    out = run("8", "--dead-zone", "5", "--lost-cycles", "10", "--log", str(tmp_path / "lost.csv"), cell=homed_sim_cell)
    assert out.returncode == 1, out.stderr
    assert "stopped: seam lost" in out.stderr
    assert "seam LOST at s" in out.stdout
    d = read_log(tmp_path / "lost.csv")
    assert np.all(np.isnan(d["lead_lateral_mm"]))
    # straight on for the dead zone and the lost cycles (5 + 11 cycles of 8/30 mm), then stop
    after = snoop(homed_sim_cell, "arm1")
    moved = math.dist([before["x"], before["y"], before["z"]], [after["x"], after["y"], after["z"]])
    assert moved <= 16 * 8 / 30 + 1.0
    assert_standing(homed_sim_cell)


def test_track_the_step_seam_end_to_end_and_agree_with_lockstep(homed_sim_cell, tmp_path):
    log, fig = tmp_path / "run.csv", tmp_path / "run.png"
    out = run("8", "--start", "i", "--length", "220", "--log", str(log), "--figure", str(fig), cell=homed_sim_cell)
    assert out.returncode == 0, out.stderr
    assert "stopped: end of seam" in out.stderr
    line = out.stdout.splitlines()[0]
    assert line.startswith("tool lateral RMS") and "end of seam" in line and "seam not lost" in line
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    d = read_log(log)
    travel = d["travel_mm"]
    assert 210 <= travel[-1] <= 225 and np.all(np.diff(travel) >= 0)
    # (how many readings arrive fresh depends on the host's load: not a verdict here)
    assert np.isfinite(d["lead_lateral_mm"]).sum() >= 20
    settled = travel > 150
    assert settled.sum() >= 50
    lat, dep = d["tool_lateral_mm"][settled], d["tool_depth_mm"][settled]
    # fresh tool-tip readings after settling arrive as the host's load allows (16 seen at load 8):
    # enough to compare, not a verdict on the tracking (the agreement below is)
    assert np.isfinite(lat).sum() >= 10 and np.isfinite(dep).sum() >= 10
    assert math.sqrt(np.nanmean(lat ** 2)) <= RT_RMS_LATERAL_MM
    assert math.sqrt(np.nanmean(dep ** 2)) <= RT_RMS_DEPTH_MM
    assert_standing(homed_sim_cell)
    # the holder was held where the layout puts it
    g = snoop(homed_sim_cell, "gmf1")
    _, T_hold = load_layout().start_poses("i")
    assert np.allclose([g["x"], g["y"], g["z"]], T_hold[:3, 3], atol=0.5)

    # the same trial in lockstep (every Reis core on virtual time, the camera chain) agrees
    from droid.experiments.trial import COLUMNS as LS_COLUMNS, TrialConfig, run_trial

    ls = run_trial(TrialConfig("agree", "i", 8.0, length_mm=220.0, seed=1, arm="full"))
    assert {"tool_lateral_mm", "tool_depth_mm"} <= set(LS_COLUMNS)
    assert_agrees_with_lockstep(d, travel, settled, ls)


def test_plus_mode_holds_its_speed_on_the_real_time_cell_and_agrees_with_lockstep(homed_sim_cell, tmp_path):
    """Issue 12: plus mode at 16 mm/s over the step seam from position (i): the achieved travel
    speed within 5 % of the commanded one, the summary line prints both, the tool on the seam
    (generous: 1 mm RMS), and the same trial in lockstep (the full arm model) agrees within
    AGREE_MEAN_MM on average after settling.  Lockstep measures 0.04 mm lateral RMS, 16.0 mm/s."""
    log = tmp_path / "plus.csv"
    out = run("16", "--mode", "plus", "--start", "i", "--length", "300", "--log", str(log), cell=homed_sim_cell,
              timeout=180)
    assert out.returncode == 0, out.stderr
    line = out.stdout.splitlines()[0]
    assert "travel speed" in line and "(commanded 16 mm/s)" in line, line
    d = read_log(log)
    travel, t = d["travel_mm"], d["t_s"]
    settled = travel > 150
    speed = float(np.polyfit(t[settled], travel[settled], 1)[0])
    assert abs(speed / 16.0 - 1.0) <= 0.05, speed
    lat = d["tool_lateral_mm"][settled]
    assert np.isfinite(lat).sum() >= 20 and math.sqrt(np.nanmean(lat ** 2)) <= 1.0
    assert_standing(homed_sim_cell)
    from droid.experiments.trial import TrialConfig, run_trial

    ls = run_trial(TrialConfig("agree", "i", 16.0, length_mm=300.0, seed=1, arm="full", mode="plus"))
    assert_agrees_with_lockstep(d, travel, settled, ls)


def start_tracking(cell, log):
    """droid-seamtrack 16 --start i on `cell`, logging to `log`, returned once it says it is
    tracking (a readiness handshake, not a sleep); killed if it never does."""
    proc = subprocess.Popen([sys.executable, "-m", SEAMTRACK, "16", "--start", "i", "--log", str(log),
                             "--cell", str(cell)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        seen = ""
        deadline = time.monotonic() + 90
        while "tracking" not in seen and time.monotonic() < deadline and proc.poll() is None:
            if select.select([proc.stderr], [], [], 0.5)[0]:
                seen += proc.stderr.readline()
        assert "tracking" in seen, seen
    except BaseException:
        proc.kill()
        proc.wait()
        raise
    return proc


def test_sigint_stops_the_run_cleanly_and_says_so(homed_sim_cell, tmp_path):
    log = tmp_path / "int.csv"
    with reaped(start_tracking(homed_sim_cell, log)) as proc:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert "stopped: interrupted (SIGINT)" in err
    assert "interrupted (SIGINT)" in out.splitlines()[0]
    d = read_log(log)
    assert len(d["s_mm"]) >= 5  # the rows up to the interrupt are kept
    assert_standing(homed_sim_cell)


def test_a_protective_stop_while_tracking_ends_the_run_naming_it(homed_sim_cell, tmp_path):
    """Issue 40 item 4: droid-servo-agent stopped for 0.3 s mid-seam (a stalled program): the
    servo runs out of way-points and brakes (FAULT_BRAKING, a protective stop).  The arm could
    follow again, but the weld stopped where it braked -- a defect -- so the run ends with
    exit 1 and one line naming the stop, keeps its log, and leaves the arm standing."""
    log = tmp_path / "braked.csv"
    with reaped(start_tracking(homed_sim_cell, log)) as proc:
        agent = next(r["pid"] for r in cell_status(homed_sim_cell) if r["name"] == "droid-servo-agent arm1")
        os.kill(agent, signal.SIGSTOP)
        try:
            time.sleep(0.3)
        finally:
            os.kill(agent, signal.SIGCONT)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    stop = [ln for ln in err.splitlines() if "stopped: " in ln]
    assert len(stop) == 1 and "stopped: fault at " in stop[0] and "(arm1 faults: " in stop[0], err
    assert "braking" in stop[0], stop
    assert "fault" in out.splitlines()[0]
    assert len(read_log(log)["s_mm"]) >= 5
    wait_for(lambda: "braking" not in snoop(homed_sim_cell, "arm1")["fault"], timeout=15,
             what="the protective stop to clear")
    assert_standing(homed_sim_cell)


@pytest.mark.shared_cell_last
def test_a_reis_fault_stops_the_run_at_once_naming_the_arm_and_its_faults(homed_sim_cell, tmp_path):
    """Issue 16 item 2: droid-servo dies mid-run (the servo agent reports FAULT_SERVO, the
    watchdog latches the amplifiers off); the tracker stops with exit 1 and one line naming
    arm1 and its faults, and still writes its log -- instead of commanding the dead arm.
    Then (issue 4, §4.1.4): arm1's Status reports the watchdog's trip beside the servo's death,
    and nothing can move it -- droid-move is not carried out."""
    log = tmp_path / "fault.csv"
    with reaped(start_tracking(homed_sim_cell, log)) as proc:
        servo = next(r["pid"] for r in cell_status(homed_sim_cell) if r["name"] == "droid-servo arm1")
        os.kill(servo, signal.SIGKILL)
        out, err = proc.communicate(timeout=30)  # generous: the rule acts on the next 30 Hz cycle
    assert proc.returncode == 1, err
    stop = [ln for ln in err.splitlines() if "stopped: " in ln]
    assert len(stop) == 1 and "stopped: fault at " in stop[0] and "(arm1 faults: " in stop[0], err
    assert "servo" in stop[0] or "watchdog" in stop[0], stop
    assert "fault" in out.splitlines()[0]
    d = read_log(log)
    assert len(d["s_mm"]) >= 5  # the rows up to the fault are kept
    st = wait_for(lambda: (lambda s: s if "watchdog" in s["fault"] else None)(snoop(homed_sim_cell, "arm1")),
                  timeout=15, what="watchdog fault reported")
    assert "servo" in st["fault"], st
    out = droid("droid.tasks.move", "arm1", "joint", "0", "0", "0", "0", "0", "0", "1", "--cell",
                str(homed_sim_cell), timeout=60)
    assert out.returncode == 1, out.stderr  # nothing can move: the command is not carried out


@pytest.mark.parametrize("args, message", [
    (["-4"], "must be > 0"),
    (["nan"], "not a finite number"),
    (["16", "--yaw-gain", "inf"], "not a finite number"),
    (["16", "--delay", "-1"], "must be >= 0"),
    (["16", "--start", "viii"], "invalid choice"),
    (["16", "--mode", "nosuch"], "invalid choice"),
    (["0", "--mode", "plus"], "must be > 0"),
    (["900", "--mode", "plus"], "<= 500 mm/s"),
    (["16", "--length", "1e308"], "(0, 10000] mm"),
    (["16", "--lost-cycles", "0"], "[1, 108000] cycles"),
    (["16", "--wrist", "nosuch"], "unknown wrist"),
    (["16", "--layout", "/nonexistent.toml"], "not found"),
    (["16", "--tool-sensor", "nosuch"], "unknown subunit"),
    (["16", "--log", "/nonexistent/dir/x.csv"], "does not exist"),
    ([], "required"),
])
def test_bad_arguments_exit_2_with_one_line(args, message, tmp_path, cell_name):
    from tests.brain.cellutil import make_cell_file

    cell = make_cell_file(tmp_path, cell_name)
    out = run(*args, cell=cell)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], out.stderr
    assert "Traceback" not in out.stderr


def test_cell_not_up_exits_1(tmp_path, cell_name):
    from tests.brain.cellutil import make_cell_file

    cell = make_cell_file(tmp_path, cell_name)
    out = run("16", cell=cell)
    assert out.returncode == 1, out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and "Traceback" not in out.stderr
