"""Checked access to one ``[world.devices.NAME]`` table of a cell file.

A device factory reads its options through :class:`DeviceOptions`: a wrong
type, a missing key or an unknown key is a :class:`~droid.cli.BadInput`
naming the file, the table and the key (exit 2), like the rest of the cell
file.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from droid.cli import BadInput, TableReader
from droid.numbers import finite_numbers


class DeviceOptions(TableReader):
    """Typed, key-checked reading of one device table (``type`` already removed); floats finite."""

    def __init__(self, world, name: str, options: dict[str, Any]) -> None:
        cell = getattr(world, "cell", None)
        path = getattr(cell, "path", None)
        super().__init__(f"{path}: [world.devices.{name}]" if path else f"[world.devices.{name}]", dict(options),
                         finite_floats=True)
        self.name = name
        self.world = world

    def bad(self, message: str, key: str | None = None) -> BadInput:
        return BadInput(f"{self.where} {key + ': ' if key else ''}{message}")

    def pose(self, key: str, default: Any = ...) -> np.ndarray:
        """A pose ``[x y z (mm), A B C (ZYZ deg)]`` as a 4x4 transform."""
        from droid.kinematics.transforms import pose_to_T

        v = self.get(key, list, default)
        if not finite_numbers(v, 6):
            raise BadInput(f"{self.where} {key} must be 6 finite numbers: x y z [mm] A B C [ZYZ deg]")
        return pose_to_T(*(float(x) for x in v))

    def device(self, key: str, what: str = "arm twin", attr: str = "wcp_global"):
        """Another device, declared before this one, that has ``attr`` (e.g. an arm twin)."""
        ref = self.get(key, str)
        devices = getattr(self.world, "devices", {})
        if ref not in devices:
            raise BadInput(f"{self.where} {key}: no device {ref!r} declared before it "
                           f"(declared: {', '.join(devices) or 'none'})")
        dev = devices[ref]
        if not callable(getattr(dev, attr, None)):
            raise BadInput(f"{self.where} {key}: device {ref!r} ({type(dev).__name__}) is not an "
                           f"{what}: it has no {attr}()")
        return dev

    def done(self) -> None:
        extra = self.unused()
        if extra:
            raise BadInput(f"{self.where} unknown key(s): {', '.join(extra)}")
