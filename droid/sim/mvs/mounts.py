"""Where a sensor sits: a frame on the tool robot's wrist seen from the workpiece on the holder's wrist (mm)."""

from __future__ import annotations

import numpy as np

from droid.kinematics.transforms import inv_homo


class Mount:
    """A frame on the tool robot's wrist seen from a workpiece on the holder's wrist."""

    def __init__(self, tool_arm, holder_arm, T_wcp_frame: np.ndarray, T_wcp_workpiece: np.ndarray) -> None:
        self.tool_arm = tool_arm
        self.holder_arm = holder_arm
        self.T_wcp_frame = np.asarray(T_wcp_frame, float)
        self.T_wcp_workpiece = np.asarray(T_wcp_workpiece, float)

    def T_global(self) -> np.ndarray:
        """The frame in the global frame (4x4, mm)."""
        return self.tool_arm.wcp_global() @ self.T_wcp_frame

    def T_global_workpiece(self) -> np.ndarray:
        return self.holder_arm.wcp_global() @ self.T_wcp_workpiece

    def T_W(self) -> np.ndarray:
        """The frame in the workpiece frame W: inv(T_global_W) @ T_global_frame (4x4, mm)."""
        return inv_homo(self.T_global_workpiece()) @ self.T_global()
