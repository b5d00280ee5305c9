"""The base of every simulated device in droid-sim (DESIGN §1: the hardware twins).

A twin imports this module, never the droid-sim program (:mod:`droid.sim.world`), so
the world's shell and its devices do not import each other.
"""
from __future__ import annotations


class Device:
    """A simulated device: ``advance(dt_s)`` one world step [s]; ``close()`` at exit."""

    name = "device"

    def advance(self, dt_s: float) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def close(self) -> None:
        pass
