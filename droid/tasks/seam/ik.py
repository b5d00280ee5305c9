"""The tool robot's joints for a wrist-centre command, nearest the last cycle's (the tracker's
reachability check before a command is sent; docs/seamtrack.md)."""
from __future__ import annotations

import numpy as np

from droid.kinematics import RobotModel


def hinted_ik(model: RobotModel | None, T_wcp, q_prev) -> np.ndarray | None:
    """The arm's joints [deg] for the wrist-centre pose ``T_wcp``: the solution nearest ``q_prev``
    (the last cycle's; zeros before the first), None without a model.  Raises Unreachable or
    ValueError where there is none."""
    if model is None:
        return None
    return model.ik(T_wcp, q_prev if q_prev is not None else np.zeros(6))
