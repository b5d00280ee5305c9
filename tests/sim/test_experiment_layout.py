"""The seam-tracking layout (droid/cells/seamtrack_layout.toml): every start position of
§6.1.2 is reachable by both robot models, and the Reis reaches the seam along its whole
length with the tool frame on it (no configuration change needed on the way)."""
import numpy as np
import pytest

from droid.kinematics import Unreachable
from droid.kinematics.transforms import inv_homo
from droid.sim.trial_cell import trial_geometry
from droid.sim.mvs.tool_sensor import seam_frame
from droid.brain.cell.cell_layout import POSITION_IDS, load_layout

CASES = [(p, "standard") for p in POSITION_IDS] + [("i", "extension30")]


@pytest.mark.parametrize("position, wrist", CASES)
def test_the_reis_reaches_the_whole_seam_from_the_start_pose(position, wrist):
    geo = trial_geometry(position, wrist=wrist)
    wp, L = geo.workpiece, geo.camera_to_tcp_mm
    T_tool_wcp = inv_homo(geo.wrist.T_wcp_tool)
    q = geo.q_tool_start_deg
    for s in np.arange(-L, wp.length_mm - L + 1e-9, 10.0):  # the tool's path while the sensor is on the seam
        T = geo.T_global_W @ seam_frame(wp, float(s)) @ T_tool_wcp
        try:
            q_next = geo.tool.ik(T, q)
        except Unreachable as exc:
            pytest.fail(f"position {position}: tool at s = {s:.0f} mm unreachable: {exc}")
        assert np.max(np.abs(q_next - q)) < 20.0, (position, s, q, q_next)  # no configuration jump
        q = q_next


@pytest.mark.parametrize("position", POSITION_IDS)
def test_start_poses_are_the_trial_geometry_and_the_holder_can_hold(position):
    lay = load_layout()
    geo = trial_geometry(position)
    T_reis, T_hold = lay.start_poses(position)
    assert np.allclose(T_reis, geo.T_global_tool6_start, atol=1e-9)
    assert np.allclose(T_hold, geo.T_global_hold6, atol=1e-6)
    assert np.allclose(geo.holder.fk(geo.holder.ik(T_hold, np.zeros(6))), T_hold, atol=1e-6)


ABB_LAYOUT = "droid/cells/abb_weld_layout.toml"


@pytest.mark.parametrize("position, wrist", CASES)
def test_the_abb_reaches_the_whole_seam_from_the_start_pose(position, wrist):
    """The ABB welding cell's layout (issue 26): the IRB 2400 reaches every start position of
    §6.1.2 and follows the whole seam without a configuration jump, the GMF1 holds it."""
    from tests.brain.cellutil import ROOT

    lay = load_layout(ROOT / ABB_LAYOUT)
    assert lay.tool_robot == "abb" and lay.robots["abb"] == "abb_irb2400"
    geo = trial_geometry(position, wrist=wrist, layout=lay)
    wp, L = geo.workpiece, geo.camera_to_tcp_mm
    assert L == pytest.approx(100.0)
    T_tool_wcp = inv_homo(geo.wrist.T_wcp_tool)
    q = geo.q_tool_start_deg
    for s in np.arange(-L, wp.length_mm - L + 1e-9, 10.0):
        T = geo.T_global_W @ seam_frame(wp, float(s)) @ T_tool_wcp
        try:
            q_next = geo.tool.ik(T, q)
        except Unreachable as exc:
            pytest.fail(f"position {position}: tool at s = {s:.0f} mm unreachable: {exc}")
        assert np.max(np.abs(q_next - q)) < 20.0, (position, s, q, q_next)
        q = q_next
