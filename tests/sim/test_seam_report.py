"""droid.tasks.seam.report: the log's CSV, the summary after settling, figures, the exp-4 std (issue 7)."""
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from droid.cli import BadInput
from droid.tasks.seam import report
from droid.tasks.seam.stops import STOP_END, STOP_LOST

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def make_row(s, lat=0.0, dep=0.0, **extra):
    base = dict(s_mm=s, lead_lateral_mm=0.1, lead_depth_mm=-0.1, lead_roll_rad=0.01, tool_lateral_mm=lat,
                tool_depth_mm=dep, tool_roll_rad=0.002, yaw_deg=0.5, pitch_deg=-0.5, t_s=s / 8.0, travel_mm=s,
                phase="tracking", lead_valid=1, ctrl_yaw_deg=0.1, ctrl_pitch_deg=0.0, delay_state="off")
    base.update(extra)
    return tuple(base[c] for c in report.COLUMNS)


def test_columns_start_with_the_nine_required_names():
    assert report.COLUMNS[:9] == ("s_mm", "lead_lateral_mm", "lead_depth_mm", "lead_roll_rad", "tool_lateral_mm",
                                  "tool_depth_mm", "tool_roll_rad", "yaw_deg", "pitch_deg")
    assert set(report.COLUMN_DOCS) == set(report.COLUMNS)
    from droid.experiments import trial

    assert trial.COLUMNS is report.COLUMNS  # one definition


def test_summarize_known_rms_after_settling_ignoring_nan():
    # before settling (s <= 150 mm): large errors that must not count
    rows = [make_row(s, lat=50.0, dep=-50.0) for s in (0.0, 100.0, 150.0)]
    # after settling: lateral +-3 -> RMS 3, max 3; depth 0, 4 -> RMS sqrt(8), max 4
    rows += [make_row(200.0, lat=3.0, dep=0.0), make_row(210.0, lat=-3.0, dep=4.0),
             make_row(220.0, lat=math.nan, dep=math.nan), make_row(math.nan, lat=99.0, dep=99.0)]
    su = report.summarize(rows, trial_id="t", stop_reason=STOP_END, stop_s_mm=230.0)
    assert su.settle_s_mm == 150.0 and su.settled_rows == 3
    assert su.rms_lateral_mm == pytest.approx(3.0) and su.max_lateral_mm == pytest.approx(3.0)
    assert su.rms_depth_mm == pytest.approx(math.sqrt(8.0)) and su.max_depth_mm == pytest.approx(4.0)
    assert su.end_s_mm == 220.0 and not su.seam_lost and math.isnan(su.lost_s_mm)
    line = report.summary_line(su)
    assert "\n" not in line and "RMS 3.00 mm" in line and "max 4.00 mm" in line and "not lost" in line


def test_summarize_seam_lost_and_where():
    rows = [make_row(float(s), lat=1.0) for s in range(0, 400, 10)]
    su = report.summarize(rows, trial_id="x", stop_reason=STOP_LOST, stop_detail="lead sensor invalid",
                          stop_s_mm=391.5, camera_to_tcp_mm=50.0)
    assert su.settle_s_mm == 100.0 and su.settled_rows == sum(1 for s in range(0, 400, 10) if s > 100)
    assert su.seam_lost and su.lost_s_mm == 391.5
    assert "seam LOST at s 391.5 mm" in report.summary_line(su)


def test_summarize_nothing_settled_gives_nan():
    su = report.summarize([make_row(10.0, lat=5.0)], stop_reason="unreachable", stop_s_mm=12.0)
    assert math.isnan(su.rms_lateral_mm) and math.isnan(su.max_depth_mm) and su.settled_rows == 0
    assert "n/a" in report.summary_line(su)
    assert report.summarize([]).rows == 0


def test_csv_round_trip_is_exact_with_nan_and_text(tmp_path):
    rng = np.random.default_rng(7)
    rows = [make_row(float(s), lat=float(rng.normal()), dep=float(rng.normal()) / 3, phase=p, delay_state=d,
                     lead_valid=v)
            for s, p, d, v in zip(np.linspace(0, 700, 50), ["dead_zone", "initial"] + ["tracking"] * 48,
                                  ["off"] * 25 + ["zeroed"] * 5 + ["delayed"] * 20, [1] * 49 + [0])]
    rows[10] = make_row(math.nan, lat=math.nan)
    path = tmp_path / "log.csv"
    assert report.write_csv(path, rows) == 50
    assert path.read_text().splitlines()[0] == ",".join(report.COLUMNS)
    back = report.read_csv(path)
    assert repr(back) == repr(rows)  # exact: repr floats, NaN stays NaN


def test_read_csv_rejects_missing_required_columns_and_tolerates_missing_extras(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("s_mm,tool_lateral_mm\n1,2\n")
    with pytest.raises(BadInput, match="missing columns"):
        report.read_csv(bad)
    few = tmp_path / "few.csv"
    few.write_text(",".join(report.REQUIRED_COLUMNS) + "\n" + ",".join(["1.5"] * 9) + "\n")
    (row,) = report.read_csv(few)
    assert row[:9] == (1.5,) * 9 and math.isnan(row[report.COLUMNS.index("t_s")])
    assert row[report.COLUMNS.index("phase")] == ""
    with pytest.raises(BadInput):
        report.read_csv(tmp_path / "absent.csv")


@pytest.mark.parametrize("panels", ["errors", "angles"])
def test_figure_writes_a_png(tmp_path, panels):
    rows = [make_row(float(s), lat=math.sin(s / 30.0), dep=0.1) for s in range(0, 500, 5)]
    path = tmp_path / f"{panels}.png"
    report.figure(path, rows, "test figure", panels, settle_s_mm=150.0, stop_s_mm=495.0, stop_label="seam lost")
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 5000
    with pytest.raises(BadInput):
        report.figure(tmp_path / "x.png", rows, "t", "wiggles")


def test_std_across_runs_on_known_offsets(tmp_path):
    # two runs identical but for a constant tool lateral offset of +-1 mm: sample std = sqrt(2) everywhere
    runs = [[make_row(float(s), lat=off) for s in range(0, 301, 10)] for off in (1.0, -1.0)]
    runs[1] = runs[1][2:]  # the second run starts later: the grid is the common span
    grid, stds = report.std_across_runs(runs, step_mm=5.0)
    assert grid[0] == 20.0 and grid[-1] == 300.0
    assert np.allclose(stds["tool_lateral_mm"], math.sqrt(2.0))
    assert np.allclose(stds["lead_lateral_mm"], 0.0)
    report.write_std_csv(tmp_path / "std.csv", grid, stds)
    lines = (tmp_path / "std.csv").read_text().splitlines()
    assert lines[0] == "s_mm,std_lead_lateral_mm,std_tool_lateral_mm,std_lead_depth_mm,std_tool_depth_mm"
    assert len(lines) == len(grid) + 1
    report.std_figure(tmp_path / "std.png", grid, stds, "std")
    assert (tmp_path / "std.png").read_bytes()[:8] == PNG_MAGIC
    with pytest.raises(ValueError):
        report.std_across_runs(runs[:1])


def test_write_table_csv_and_markdown(tmp_path):
    recs = [{"id": "1.1", "rms_lateral_mm": "0.100"}, {"id": "1.2", "rms_lateral_mm": ""}]
    report.write_table(tmp_path / "s.csv", tmp_path / "s.md", recs, title="T")
    assert (tmp_path / "s.csv").read_text().splitlines() == ["id,rms_lateral_mm", "1.1,0.100", "1.2,"]
    md = (tmp_path / "s.md").read_text().splitlines()
    assert md[0] == "# T" and md[2] == "| id | rms_lateral_mm |" and md[4] == "| 1.1 | 0.100 |"


TASKS = Path(__file__).resolve().parents[2] / "droid" / "tasks"
# droid.observe: droid-seamtrack --record (observers read the Brain's databases only, like a task)
# droid.numbers: the range check of numbers read from files, a leaf like droid.cli
TASK_MAY_IMPORT = ("droid.brain", "droid.kinematics", "droid.cli", "droid.numbers", "droid.tasks", "droid.observe",
                   "droid.guard")  # the collision guard's bodies: droid-move refuses a colliding move


def test_tasks_import_only_brain_kinematics_cli_and_tasks():
    """docs/design.md §7: a task sees the Brain's databases, never a device or the simulator."""
    from tests.layering import droid_imports, within

    for path in TASKS.rglob("*.py"):
        for n in droid_imports(path):
            assert within(n, TASK_MAY_IMPORT), (path, n)


def test_report_import_does_not_load_matplotlib_or_the_simulator():
    code = ("import sys, droid.tasks.seam.report;"
            "print(sorted(m for m in sys.modules if m.startswith(('droid.sim', 'matplotlib'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_summary_line_prints_the_achieved_travel_speed_beside_the_commanded():
    # make_row: t_s = s / 8: the tool advanced at 8 mm/s
    rows = [make_row(float(s)) for s in range(0, 400, 10)]
    su = report.summarize(rows, stop_reason=STOP_END, commanded_mm_s=16.0)
    assert su.travel_speed_mm_s == pytest.approx(8.0)
    assert "travel speed 8.0 mm/s (commanded 16 mm/s)" in report.summary_line(su)
    assert "travel speed" not in report.summary_line(report.summarize(rows, stop_reason=STOP_END))
