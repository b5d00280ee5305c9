"""Where the Reis motion controller's programs meet, from the cell file's [subunits.NAME] table.

Keys (with defaults)::

    vme = "shm://droid.{cell}.NAME.vme"          # the VME register map (droid-sim's twin)
    servo = "ipc://{run}/NAME.servo"             # servo command messages (servo binds PULL)
    servo_status = "ipc://{run}/NAME.servostat"  # servo status messages (servo binds PUB)
"""
from __future__ import annotations

from dataclasses import dataclass

from droid.brain.cell.cellfile import Cell, Subunit
from droid.cli import BadInput


@dataclass(frozen=True)
class ReisEndpoints:
    vme: str
    servo: str
    servo_status: str


def reis_endpoints(cell: Cell, sub: Subunit) -> ReisEndpoints:
    o = sub.options
    vme = o.get("vme", f"shm://droid.{cell.name}.{sub.name}.vme")
    servo = o.get("servo", f"ipc://{cell.run_dir}/{sub.name}.servo")
    status = o.get("servo_status", f"ipc://{cell.run_dir}/{sub.name}.servostat")
    for key, val in (("vme", vme), ("servo", servo), ("servo_status", status)):
        if not isinstance(val, str):
            raise BadInput(f"{cell.path}: [subunits.{sub.name}] {key} must be a string")
    return ReisEndpoints(vme, servo, status)
