"""Where everything is at the start of a trial: the layout applied to one workpiece and position.

From the seam-tracking layout (droid/cells/seamtrack_layout.toml): the
workpiece frame W in the global frame for a start position (§6.1.2), the GMF1
wrist-centre pose that holds it there (``global T W (GMF1)6 T W^-1``), and the
Reis start pose: the tool frame on the seam's straight extension
CAMERA_TO_TCP before the seam start, so the lead sensor's laser line lies on
the seam start (§6.1.1), tool axis along the surface normal, travel along the
seam.  Both robots' joint angles come from their models (the planner's pick
from the zero pose, as a droid-move from home would give).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from droid.cli import BadInput
from droid.kinematics import RobotModel, Unreachable, load_robot
from droid.kinematics.transforms import inv_homo
from droid.sim.mvs.tool_sensor import seam_frame
from droid.sim.workpiece import Workpiece, load_workpiece
from droid.brain.cell_layout import Layout, Wrist, load_layout


@dataclass(frozen=True)
class TrialGeometry:
    """Frames of one trial (4x4, mm, global unless named otherwise)."""

    layout: Layout
    wrist: Wrist
    workpiece: Workpiece
    position: str
    reis: RobotModel  # with its base
    fanuc: RobotModel  # with its base
    T_global_W: np.ndarray
    T_hold6_W: np.ndarray  # (GMF1)6 T W, the mount
    T_global_hold6: np.ndarray  # GMF1 wrist centre (held still)
    q_hold_deg: np.ndarray
    T_global_reis6_start: np.ndarray  # Reis wrist centre at the start
    q_reis_start_deg: np.ndarray

    @property
    def camera_to_tcp_mm(self) -> float:
        return self.wrist.camera_to_tcp_mm

    @property
    def T_W_global(self) -> np.ndarray:
        return inv_homo(self.T_global_W)


@lru_cache(maxsize=8)
def _robot(name: str, base_key: tuple) -> RobotModel:
    base = np.array(base_key, float).reshape(4, 4)
    return load_robot(name).with_base(base)


def robot_with_base(layout: Layout, subunit: str) -> RobotModel:
    """The robot model of a layout subunit, placed at its base."""
    name = layout.robots.get(subunit)
    if not name:
        raise BadInput(f"layout {layout.source}: [robots] names no model for {subunit}")
    return _robot(name, tuple(layout.base(subunit).ravel().tolist()))


def trial_geometry(position: str, workpiece: str | None = None, wrist: str = "standard",
                   layout: Layout | None = None) -> TrialGeometry:
    """The frames of a trial at ``position`` (i..vii) with ``workpiece`` (default: the position's)."""
    lay = layout or load_layout()
    pos = lay.position(position)
    wr = lay.wrist(wrist)
    wp = load_workpiece(workpiece or pos.workpiece)
    reis = robot_with_base(lay, lay.tool_robot)
    fanuc = robot_with_base(lay, lay.holder_robot)
    L = wr.camera_to_tcp_mm
    T_gW = pos.T_global_W(L)
    mount = lay.mount(wp.name)
    T_hold = T_gW @ inv_homo(mount)
    try:
        q_hold = fanuc.ik(T_hold, np.zeros(6))
    except Unreachable as exc:
        raise BadInput(f"position {position}: the {lay.holder_robot} cannot hold {wp.name} there: {exc}") from None
    T_tool = T_gW @ seam_frame(wp, -L)
    T_reis = T_tool @ inv_homo(wr.T_wcp_tool)
    try:
        q_reis = reis.ik(T_reis, np.zeros(6))
    except Unreachable as exc:
        raise BadInput(f"position {position}: the {lay.tool_robot} cannot reach the start: {exc}") from None
    return TrialGeometry(layout=lay, wrist=wr, workpiece=wp, position=position, reis=reis, fanuc=fanuc,
                         T_global_W=T_gW, T_hold6_W=mount, T_global_hold6=fanuc.fk(q_hold), q_hold_deg=q_hold,
                         T_global_reis6_start=T_reis, q_reis_start_deg=q_reis)
