"""droid-contact without a running cell (issue 27 item 5): bad input is one line and exit 2
before anything moves; the start pose puts the nozzle over the lower plate; the summary."""
from __future__ import annotations

import math

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.kinematics.transforms import inv_homo
from droid.tasks.contact import report
from droid.tasks.contact.prog import ContactRun, build_parser
from droid.brain.cell.cell_layout import load_layout
from tests.brain.cellutil import droid, make_cell_file

PROG = "droid.tasks.contact.prog"


@pytest.mark.parametrize("args, message", [
    (["arm1", "--force", "0"], "argument --force: must be > 0"),
    (["arm1", "--force", "nan"], "argument --force"),
    (["arm1", "--speed", "500"], "argument --speed: must be > 0 and <= 100 mm/s"),
    (["arm1", "--length", "-3"], "argument --length"),
    (["arm1", "--start", "ix"], "argument --start"),
    (["arm1", "--force", "70"], "--force 70 N: must be < force_max_n 60 N"),
    (["arm1", "--ft", "mvs"], "--ft mvs: is a line_laser subunit, not a force/torque sensor (ft6)"),
    (["arm1", "--ft", "nothere"], "nothere"),
    (["gmf1", "--start", "i"], "puts the tool on arm1, not gmf1"),
    (["mvs"], "not an arm"),
    (["arm1", "--log", "/nonexistent/dir/x.csv"], "directory of /nonexistent/dir/x.csv does not exist"),
])
def test_bad_arguments_are_one_line_and_exit_2(tmp_path, cell_name, args, message):
    cell = make_cell_file(tmp_path, cell_name)
    out = droid(PROG, *args, "--cell", str(cell), timeout=60)
    assert out.returncode == 2, (out.returncode, out.stderr)
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in out.stderr, out.stderr


def test_bad_gains_are_one_line_and_exit_2(tmp_path, cell_name):
    cell = make_cell_file(tmp_path, cell_name)
    gains = tmp_path / "g.toml"
    gains.write_text("admittance_mm_per_n_s = 3.0\n")  # K k T = 3 x 20 x 2/60 = 2: unstable
    out = droid(PROG, "arm1", "--gains", str(gains), "--cell", str(cell), timeout=60)
    assert out.returncode == 2 and "the loop is unstable at K k T >= 2" in out.stderr, out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


def test_without_a_running_cell_it_exits_1_in_one_line(tmp_path, cell_name):
    out = droid(PROG, "arm1", "--cell", str(make_cell_file(tmp_path, cell_name)), timeout=60)
    assert out.returncode == 1 and "is the cell up?" in out.stderr and "Traceback" not in out.stderr, out.stderr


def test_the_start_pose_puts_the_nozzle_over_the_lower_plate(tmp_path, cell_name):
    cell = load_cell(make_cell_file(tmp_path, cell_name))
    args = build_parser().parse_args(["arm1", "--start", "i", "--lateral", "-25", "--clearance", "5"])
    job = ContactRun(args, cell)
    T_arm, T_hold = job.start_pose("i")
    layout = load_layout(None)
    T_gW = T_hold @ layout.mount("step_input")  # where the holder puts the workpiece
    touch_W = inv_homo(T_gW) @ T_arm @ job.T_wcp_touch
    assert np.allclose(touch_W[:3, 3], [0.0, -25.0, 5.0], atol=1e-6)  # 5 mm over the lower plate (y < 0)
    assert np.allclose(touch_W[:3, 0], [0.0, 0.0, -1.0], atol=1e-9)  # the tool axis into the surface
    assert np.allclose(touch_W[:3, 2], [1.0, 0.0, 0.0], atol=1e-9)  # travel along the seam
    # the nozzle is 15 mm short of the wrist's tool point along the tool axis (cells/sim.toml's touch)
    tool_W = inv_homo(T_gW) @ T_arm @ job.wrist.T_wcp_tool
    assert np.allclose(tool_W[:3, 3], [0.0, -25.0, -10.0], atol=1e-6)


def test_the_summary_counts_the_path_after_settling_only():
    rows = [(0.0, "approach", 0.0, 20.0, 0.1, 0.0, 0.0, 0.0),
            (0.5, "settle", 25.0, -5.0, 1.0, 0.9, 0.0, 0.0),
            (1.0, "path", 30.0, -10.0, 1.0, 1.0, 0.3, 10.0),  # within the settling second: not counted
            (2.0, "path", 21.0, -1.0, 1.0, 1.0, 10.0, 10.0),
            (2.5, "path", 18.0, 2.0, 1.0, 1.0, 15.0, 12.0)]
    s = report.summary(rows)
    assert s.cycles == 2 and s.max_n == pytest.approx(2.0) and s.rms_n == pytest.approx(math.sqrt(2.5))
    assert s.mean_speed_mm_s == pytest.approx(11.0) and s.peak_force_n == pytest.approx(30.0)
    line = s.line(20.0, 10.0, 200.0, "end", "200 mm done")
    assert line.startswith("normal force RMS error 1.58 N, max 2.00 N") and "stop: end (200 mm done)" in line
    assert math.isnan(report.summary(rows[:2]).rms_n)  # never reached the path: no figure invented
