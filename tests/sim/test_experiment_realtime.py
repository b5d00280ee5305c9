"""droid-experiment --realtime: the trial's cell file (no processes here; the end-to-end
real-time trial is tests/tasks/test_seamtrack_cell.py and test_experiment_cli.py)."""
import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.kinematics.transforms import pose_to_T
from droid.sim.trial_cell import trial_geometry
from droid.experiments.realtime import trial_cell_text
from droid.experiments.trial import TrialConfig
from droid.tasks.seam.report import COLUMNS, log_row, read_csv, write_csv
from droid.tasks.seam.delay import Reading


@pytest.mark.parametrize("position, wrist, workpiece", [("iii", "standard", "step_input"),
                                                        ("vii", "standard", "ramp_r300"),
                                                        ("i", "extension30", "step_input")])
def test_trial_cell_puts_the_layout_into_the_world(tmp_path, position, wrist, workpiece):
    cfg = TrialConfig("t", position, 16.0, workpiece=workpiece, wrist=wrist, seed=7)
    path = tmp_path / "c.toml"
    path.write_text(trial_cell_text(cfg, "xtrial", tmp_path / "run"))
    cell = load_cell(path)
    assert cell.name == "xtrial" and cell.run_dir == tmp_path / "run" and cell.world["seed"] == 7
    geo = trial_geometry(position, workpiece, wrist)
    cam, tool = cell.world["devices"]["mvs_camera"], cell.world["devices"]["tool_sensor"]
    assert cam["workpiece"] == tool["workpiece"] == workpiece
    assert cam["holder_robot"] == tool["holder_robot"] == "gmf1_karel"
    for dev in (cam, tool):
        assert np.allclose(pose_to_T(*dev["workpiece_mount"]), geo.T_hold6_W, atol=1e-5)
    assert np.allclose(pose_to_T(*cam["sensor_pose"]), geo.wrist.T_wcp_sensor, atol=1e-5)
    assert np.allclose(pose_to_T(*tool["tool_pose"]), geo.wrist.T_wcp_tool, atol=1e-5)


def test_a_task_log_reads_back_as_trial_rows(tmp_path):
    rows = [log_row(s_mm=float(i), t_s=i / 10, lead=Reading(0.1, 0.2, 0.0, i % 2 == 0), tool=(0.5, -0.5, 0.0),
                    out=None, camera_to_tcp_mm=100.0) for i in range(5)]
    write_csv(tmp_path / "l.csv", rows)
    back = read_csv(tmp_path / "l.csv")
    assert len(back) == 5 and len(back[0]) == len(COLUMNS)
    assert back[1][COLUMNS.index("lead_lateral_mm")] != back[1][COLUMNS.index("lead_lateral_mm")]  # NaN: invalid
    assert back[2][COLUMNS.index("tool_lateral_mm")] == 0.5 and back[2][COLUMNS.index("phase")] == "dead_zone"
