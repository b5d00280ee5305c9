"""The keys of a contact plan: ``trial = "contact"`` sweeps the lockstep force-control trial
(droid.experiments.contact_trial; issue 27 item 5; thesis §7.3, force control as the next
sensor task of a DROID cell).

    name = "contact_seeds"
    trial = "contact"
    [defaults]
    force_n = 20
    speed_mm_s = 10
    length_mm = 200
    [sweep]
    seed = [1, 2, 3]

Keys of ``[defaults]`` and ``[sweep]`` (fields of
:class:`droid.experiments.contact_trial.ContactTrialConfig`, :data:`CONTACT_FIELDS`):

================  ==========================================================
``force_n``        the normal force to hold [N], in (0, force_max_n of the gains)
``speed_mm_s``     speed along the path [mm/s], in (0, 500]
``length_mm``      the path's length [mm], in (0, 10000]
``seed``           the trial's seed, integer in [0, 2**31 - 1] (used as given)
``workpiece``      a bundled name or a path relative to the plan file; it needs a ``[contact]`` table
``position``       a start position of the layout: i .. vii (where the workpiece is fixed)
``lateral_mm``     the path beside the seam [mm]; the start must lie over the lower plate
``clearance_mm``   the tool above the surface at the start [mm], in [0, approach_max_mm of the gains)
``gains``          a gains file, a path relative to the plan file (default: the bundled gains)
================  ==========================================================

Unset keys take :data:`CONTACT_DEFAULTS` (ContactTrialConfig's).  A seam-tracking key
(``yaw_gain``, ``delay_cycles`` ...) in a contact plan is refused in one line, as an unknown
key is.  Checks that need two keys (the force against the gains' ``force_max_n``, the
clearance against their ``approach_max_mm``, the start over the workpiece's lower plate)
run per trial; each failure is one BadInput line naming the plan, the key and the value.
"""
from __future__ import annotations

import os
from dataclasses import fields
from pathlib import Path

import numpy as np

from droid.cli import BadInput
from droid.experiments.contact_trial import HEARTBEAT_HZ, ContactTrialConfig
from droid.tasks.seam.params import MAX_RUN_LENGTH_MM, MAX_SPEED_MM_S

CONTACT_FIELDS = ("force_n", "speed_mm_s", "length_mm", "seed", "workpiece", "position", "lateral_mm",
                  "clearance_mm", "gains")
_CFG_DEFAULTS = {f.name: f.default for f in fields(ContactTrialConfig)}
#: Values of keys a contact plan leaves unset: ContactTrialConfig's (gains None: the bundled file).
CONTACT_DEFAULTS = {k: _CFG_DEFAULTS[k] for k in CONTACT_FIELDS}
#: Largest |lateral_mm| checked before the workpiece is known [mm] (then: over the lower plate).
MAX_LATERAL_MM = MAX_RUN_LENGTH_MM


class ContactKeys:
    """The checks of a contact plan's values, on the plan's checker (droid.experiments.plan)."""

    fields = CONTACT_FIELDS
    defaults = CONTACT_DEFAULTS

    def __init__(self, checker) -> None:
        self.checker = checker
        self._gains: dict[str, tuple[str, object]] = {}  # value as written -> (resolved path, Gains)
        self._pieces: dict[str, object] = {}  # resolved spec -> Workpiece

    def check(self, where: str, key: str, value):
        """The value, normalised (floats as floats; workpiece and gains checked by loading them)."""
        c = self.checker

        def number() -> float:
            if not (isinstance(value, (int, float)) and not isinstance(value, bool)
                    and np.isfinite(value)):
                raise c.bad(where, key, value, "must be a finite number")
            return float(value)

        if key in ("speed_mm_s", "length_mm"):
            v = number()
            hi, unit = (MAX_RUN_LENGTH_MM, "mm") if key == "length_mm" else (MAX_SPEED_MM_S, "mm/s")
            if not 0.0 < v <= hi:
                raise c.bad(where, key, value, f"must be in (0, {hi:g}] {unit}")
            return v
        if key == "force_n":
            v = number()
            if v <= 0.0:
                raise c.bad(where, key, value, "must be > 0 N")
            return v
        if key == "clearance_mm":
            v = number()
            if v < 0.0:
                raise c.bad(where, key, value, "must be >= 0 mm (the tool starts above the surface)")
            return v
        if key == "lateral_mm":
            v = number()
            if abs(v) > MAX_LATERAL_MM:
                raise c.bad(where, key, value, f"must be within [-{MAX_LATERAL_MM:g}, {MAX_LATERAL_MM:g}] mm")
            return v
        if key == "seed":
            if not isinstance(value, int) or isinstance(value, bool):
                raise c.bad(where, key, value, "must be an integer")
            if not 0 <= value <= 2 ** 31 - 1:
                raise c.bad(where, key, value, f"must be within [0, {2 ** 31 - 1}]")
            return value
        if key == "position":
            return c.check(where, key, value)
        if key == "workpiece":
            c.workpiece(where, c.text(where, key, value, "must be a bundled workpiece name or a path"))
            wp = self.workpiece(c.resolved(value))
            if wp.contact is None:
                raise c.bad(where, key, value, "has no [contact] table (no contact model: docs/contact.md)")
            if not wp.planar:  # the world has its contact; the trial's start and path do not follow it
                raise c.bad(where, key, value, "is a 3-D workpiece: the force trial's start and path lie in "
                            "W's x-y plane (plane workpieces only; docs/contact.md)")
            return value
        if key == "gains":
            self.gains(where, c.text(where, key, value, "must be a gains file's path (relative to the plan)"))
            return value
        raise AssertionError(key)

    def workpiece(self, spec: str):
        """The loaded workpiece of a checked spec (loaded once per plan)."""
        if spec not in self._pieces:
            from droid.sim.workpiece import load_workpiece

            self._pieces[spec] = load_workpiece(spec)
        return self._pieces[spec]

    def gains(self, where: str, value: str | None):
        """(the path load_gains takes, the Gains) of a gains value (None: the bundled file)."""
        from droid.tasks.contact.core import load_gains

        if value in self._gains:
            return self._gains[value]
        if value is None:
            spec = None
        else:
            path = Path(value) if os.path.isabs(value) else self.checker.plan_dir / value
            if not path.is_file():
                raise self.checker.bad(where, "gains", value, f"file not found ({path})")
            spec = str(path.resolve())
        try:
            g = load_gains(spec, HEARTBEAT_HZ)
        except BadInput as exc:
            raise self.checker.bad(where, "gains", value, str(exc)) from None
        self._gains[value] = (spec, g)
        return self._gains[value]

    def config(self, tid: str, params: dict, where_of) -> ContactTrialConfig:
        """The trial's config, after the checks that need two keys (``where_of(key)``: its table)."""
        c = self.checker
        spec, g = self.gains(where_of("gains"), params["gains"])
        if not params["force_n"] < g.force_max_n:
            raise c.bad(where_of("force_n"), "force_n", params["force_n"],
                        f"must be < force_max_n {g.force_max_n:g} N of the gains ({spec or 'bundled'})")
        if not params["clearance_mm"] < g.approach_max_mm:
            raise c.bad(where_of("clearance_mm"), "clearance_mm", params["clearance_mm"],
                        f"must be < approach_max_mm {g.approach_max_mm:g} mm of the gains "
                        f"({spec or 'bundled'}): the approach would end before the surface")
        wp_spec = c.resolved(params["workpiece"])
        wp = self.workpiece(wp_spec)
        x0 = _CFG_DEFAULTS["x_start_mm"]
        if wp.surface_height(np.array([x0, params["lateral_mm"]])) != 0.0:
            raise c.bad(where_of("lateral_mm"), "lateral_mm", params["lateral_mm"],
                        f"the tool's start (x {x0:g}, y {params['lateral_mm']:g} mm in W) is not over "
                        f"{wp.name}'s lower plate")
        kw = {**params, "workpiece": wp_spec, "gains": spec}
        # a long or slow path gets the time it needs (the trial's 60 s covers the bundled 200 mm at 10 mm/s)
        kw["max_s"] = max(_CFG_DEFAULTS["max_s"], 30.0 + 1.5 * params["length_mm"] / params["speed_mm_s"])
        return ContactTrialConfig(**kw)
