"""The base of every simulated device in droid-sim (docs/design.md §1: the hardware twins).

A twin imports this module, never the droid-sim program (:mod:`droid.sim.world`), so
the world's shell and its devices do not import each other.
"""
from __future__ import annotations

import math

from droid.cli import BadInput


class Device:
    """A simulated device: ``advance(dt_s)`` one world step [s]; ``close()`` at exit.

    ``step_s`` [s]: the longest world time the device may be advanced by in one call, so the
    real-time world (droid-sim) calls it only every ``step_s`` of world time, with the whole
    time owed, instead of at every 1 ms step (docs/architecture.md "The world's rates").  0:
    every world step (an arm twin, whose register map the servo reads at 500 Hz).  A device
    with a rate of its own (a camera's frames, an RDT stream, a serial line's bytes) keeps
    that rate on world time whatever ``dt_s`` it is given; the lockstep runners step their
    twins themselves and never read this.

    ``wake_hz`` [Hz]: how often the real-time world must wake for this device -- the fastest
    rate anything outside it reads what it writes (droid-servo reads an arm's register map at
    500 Hz) -- or None: as often as it is stepped (every ``step_s``; every world step for 0).
    The world wakes at the fastest of its devices' rates and takes the world steps in between
    back to back (:meth:`droid.sim.world.World.steps_per_wake`, docs/architecture.md "The
    world's rates")."""

    name = "device"
    step_s = 0.0
    wake_hz: float | None = None

    def advance(self, dt_s: float) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def close(self) -> None:
        pass


def wake_hz_of(dev: Device, rate_hz: float) -> float:
    """The rate [Hz] the real-time world must wake at for ``dev`` when it steps at ``rate_hz``:
    its ``wake_hz``, else its own rate (1 / ``step_s``), else every world step; never above
    ``rate_hz`` (a world step is the finest it has)."""
    w = dev.wake_hz
    if w is None:
        w = 1.0 / dev.step_s if dev.step_s > 0 else rate_hz
    return min(float(w), rate_hz)


def arm_subunit(world, name: str, options: dict, known) -> tuple[str, object]:
    """An arm twin's factory preamble: its options checked against ``known`` and the arm subunit
    it serves (option ``subunit``, default the device's name).  Returns ``(where, subunit)``;
    ``where`` names the device table in messages.  BadInput (one line) otherwise."""
    return cell_arm_subunit(world.cell, name, options, known)


def cell_arm_subunit(cell, name: str, options: dict, known) -> tuple[str, object]:
    """:func:`arm_subunit` from the cell alone (a lockstep assembly has no world)."""
    where = f"{cell.path}: [world.devices.{name}]"
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise BadInput(f"{where} unknown option(s) {', '.join(unknown)} (known: type, {', '.join(known)})")
    sub = cell.subunit(options.get("subunit", name))
    if not sub.is_arm:
        raise BadInput(f"{where} subunit {sub.name} is not an arm")
    return where, sub


def number_options(options: dict, keys, where: str) -> dict[str, float]:
    """The finite numbers among ``keys`` that ``options`` gives, as floats (a twin's parameter
    overrides); a bool, a non-number or nan/inf is BadInput naming the key (one line)."""
    out: dict[str, float] = {}
    for key in keys:
        if key in options:
            v = options[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise BadInput(f"{where} {key} must be a number, got {v!r}")
            out[key] = float(v)
    return out
