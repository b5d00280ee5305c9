"""The ``fixed_arm`` world device: an arm twin that does not move (thesis §5.3 experiments).

``[world.devices.NAME]`` with ``type = "fixed_arm"`` and ``wcp = [x, y, z, A, B, C]``
(mm, ZYZ deg): its wrist-centre pose in the global frame.  It implements the
arm-twin interface the sensors need (``wcp_global() -> 4x4`` [mm]).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from droid.sim.device_options import DeviceOptions
from droid.sim.device import Device


class FixedArm(Device):
    """An arm twin held at one wrist-centre pose (the arm-twin interface: ``wcp_global()``)."""
    wake_hz = 0.0  # it has no step: the world need never wake for it

    def __init__(self, name: str, T_global_wcp: np.ndarray) -> None:
        self.name = name
        self._T = np.array(T_global_wcp, float)

    def wcp_global(self) -> np.ndarray:
        """The wrist-centre pose in the global frame (4x4, mm)."""
        return self._T.copy()

    def advance(self, dt_s: float) -> None:
        pass



# -- factory (droid.sim.world.DEVICE_TYPES) -------------------------------------

def fixed_arm(world, name: str, options: dict[str, Any]) -> FixedArm:
    opts = DeviceOptions(world, name, options)
    T = opts.pose("wcp")
    opts.done()
    return FixedArm(name, T)
