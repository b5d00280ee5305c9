"""The Reis Robotstar V15 in droid-sim: its plant behind a shared-memory VME register map.

Device type ``reis_vme`` (cell file)::

    [world.devices.arm1]
    type = "reis_vme"
    subunit = "arm1"        # whose [subunits.arm1] vme URL and base pose to use (default: the device name)
    seed = 7                # power-up encoder values and joint positions (default: the world seed)

droid-servo and droid-watchdog open the same bytes with ``open_vme(url)``.
The device also implements the arm-twin interface of the world:
``wcp_global()`` — the true wrist-centre pose [mm] in the global frame, used
by the camera twin.
"""
from __future__ import annotations

import numpy as np

from droid.cli import BadInput
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T
from droid.sim.reis_plant import ReisPlant, ReisPlantParams
from droid.sim.vme_shm import SharedVmeMap
from droid.sim.world import Device
from droid.subunits.reis.endpoints import reis_endpoints


class ReisDevice(Device):
    def __init__(self, name: str, shared: SharedVmeMap, plant: ReisPlant, model) -> None:
        self.name = name
        self.shared = shared
        self.plant = plant
        self.model = model

    def advance(self, dt_s: float) -> None:
        self.plant.advance(dt_s)

    def wcp_global(self) -> np.ndarray:
        return self.model.fk(self.plant.joint_deg)

    def close(self) -> None:
        close = getattr(self.plant, "close", None)
        if close is not None:
            close()
        self.shared.close()


def make_reis(world, name: str, options: dict) -> ReisDevice:
    cell = world.cell
    sub = cell.subunit(options.get("subunit", name))
    url = reis_endpoints(cell, sub).vme
    if not url.startswith("shm://"):
        raise BadInput(f"[world.devices.{name}] the simulated VME map needs a shm:// URL, got {url!r}")
    seed = int(options.get("seed", world.seed))
    shared = SharedVmeMap.create(url[len("shm://"):], replace=True)
    try:
        plant = ReisPlant(ReisPlantParams(), seed, regs=shared.buf)
        model = load_robot(sub.robot).with_base(pose_to_T(*sub.base))
    except BaseException:
        shared.close()
        raise
    return ReisDevice(name, shared, plant, model)
