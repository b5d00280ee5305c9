"""Sweep plans: a researcher's own experiment as a TOML file (issue 15).

    name = "gains"                      # the output directory's name: letters, digits, _ . -
    description = "..."                 # optional
    [defaults]                          # optional: a value for every trial
    position = "iii"
    speed_mm_s = 16
    [sweep]                             # each key a list; the trials are their cartesian product
    yaw_gain = [0.1, 0.15, 0.2]
    delay_cycles = [0, 1, 2]

Keys of ``[defaults]`` and ``[sweep]`` (the fields of
:class:`droid.experiments.trial.TrialConfig`, :data:`FIELDS`):

================  ==========================================================
``workpiece``      a bundled name (``step_input``) or a path, relative to the plan file
``position``       a start position of the layout: i .. vii (thesis §6.1.2)
``speed_mm_s``     travel speed [mm/s], in (0, 500]
``yaw_gain``       proportional gains (§5.5), in [0, 10]
``pitch_gain``
``delay_cycles``   a transport delay of this many 30 Hz cycles, integer in [0, 108000] (§6.2.5)
``delay_at_mm``    where the delay starts [mm], in [0, 10000]
``wrist``          a wrist of the layout: standard, extension30 (§6.2.7)
``mode``           the tracking mode (passed to TrialConfig(mode=...) when it has one)
``arm``            fast | full (the Reis model)
``sensor``         ideal | camera (the lead sensor model)
``seed``           the trial's seed, integer in [0, 2**31 - 1] (used as given)
``length_mm``      the tool's run length [mm], in (0, 10000] (default: the seam's length)
================  ==========================================================

Unset keys take :data:`BUILTIN_DEFAULTS`.  The trials are the product of
the ``[sweep]`` lists in the order written (the last key varies fastest).
Each trial's ID is a hash of its parameters (:func:`trial_id`), so it is the
same whatever else the plan sweeps, which is what ``--resume`` relies on.

A top-level ``cell`` key runs every trial on a cell file (``TrialConfig.cell``,
droid.sim.trial_cell): a path relative to the plan file, or a bundled cell's name
(``abb_weld.toml``), as a cell's ``layout`` key is found.  Positions and wrists are then the
cell's layout's; the cell joins every trial's parameters (and so its ID) as written.

A top-level ``trial`` key chooses the trial a plan sweeps: ``"seamtrack"`` (the
default: the seam-tracking trial above) or ``"contact"`` (the lockstep force-control
trial, thesis §7.3; its keys: droid.experiments.contact_plan).

Bad input raises :class:`~droid.cli.BadInput` with one line naming the plan,
the key and the value.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import re
from dataclasses import dataclass, fields
from pathlib import Path

from droid.cli import BadInput, read_toml
from droid.numbers import NumberError, check_numbers
from droid.tasks.seam.params import MAX_CYCLES, MAX_GAIN, MAX_RUN_LENGTH_MM, MAX_SPEED_MM_S

PLAN_DIR = Path(__file__).parent / "plans"

FIELDS = ("workpiece", "position", "speed_mm_s", "yaw_gain", "pitch_gain", "delay_cycles", "delay_at_mm",
          "wrist", "mode", "arm", "sensor", "seed", "length_mm")

#: Values of keys a plan leaves unset (as TrialConfig's, but the sweeps' lead sensor "ideal";
#: workpiece None: the position's own; length_mm None: the seam's length; mode None: TrialConfig's).
BUILTIN_DEFAULTS = {"workpiece": None, "position": "i", "speed_mm_s": 16.0, "yaw_gain": 0.15,
                    "pitch_gain": 0.25, "delay_cycles": 0, "delay_at_mm": 150.0, "wrist": "standard",
                    "mode": None, "arm": "full", "sensor": "ideal", "seed": 1, "length_mm": None}

_TOP_KEYS = ("name", "description", "trial", "cell", "defaults", "sweep")
TRIAL_SEAMTRACK, TRIAL_CONTACT = "seamtrack", "contact"
#: The trials a plan can sweep (its ``trial`` key; the first is the default).
TRIAL_KINDS = (TRIAL_SEAMTRACK, TRIAL_CONTACT)
_NAME = re.compile(r"[A-Za-z0-9_.-]+")


@dataclass(frozen=True)
class PlanTrial:
    """One trial of a plan: its ID, its parameters (FIELDS -> value) and its TrialConfig."""

    id: str
    index: int  # 0-based position in the plan's product
    params: dict
    config: object  # TrialConfig (a contact plan's: contact_trial.ContactTrialConfig)
    table: str  # the plan's name (the output subdirectory)
    kind: str = TRIAL_SEAMTRACK  # the plan's trial (TRIAL_KINDS)

    def describe(self) -> str:
        """One line: index, ID and the swept parameters."""
        shown = " ".join(f"{k}={_show(v)}" for k, v in self.params.items() if v is not None)
        return f"{self.index:4d} {self.id}  {shown}"


@dataclass(frozen=True)
class Plan:
    name: str
    description: str
    source: str
    defaults: dict
    sweep: dict  # key -> list of values, in file order
    trials: tuple[PlanTrial, ...]
    trial: str = TRIAL_SEAMTRACK  # the trial it sweeps (TRIAL_KINDS)

    @property
    def fields(self) -> tuple[str, ...]:
        """The parameter keys of its trials, in results.csv order."""
        if self.trial == TRIAL_SEAMTRACK:
            return FIELDS
        from droid.experiments.contact_plan import CONTACT_FIELDS

        return CONTACT_FIELDS


def _show(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def trial_id(params: dict) -> str:
    """A stable ID from the trial's parameters: ``t`` + 10 hex digits of their SHA-256."""
    canon = json.dumps({k: params[k] for k in sorted(params)}, sort_keys=True, separators=(",", ":"))
    return "t" + hashlib.sha256(canon.encode()).hexdigest()[:10]


def bundled_plans() -> list[str]:
    """Names of the example plans shipped in droid/experiments/plans/."""
    return sorted(p.stem for p in PLAN_DIR.glob("*.toml"))


def resolve_plan_path(spec: str) -> Path:
    """A plan by path, or by the name of a bundled example plan."""
    path = Path(spec)
    if path.is_file():
        return path
    if os.sep not in spec and not spec.endswith(".toml") and (PLAN_DIR / f"{spec}.toml").is_file():
        return PLAN_DIR / f"{spec}.toml"
    raise BadInput(f"plan file not found: {spec} (bundled plans: {', '.join(bundled_plans())})")


def _trial_config_fields() -> set[str]:
    from droid.experiments.trial import TrialConfig

    return {f.name for f in fields(TrialConfig)}


class _Checker:
    """Type and range checks of one plan's values; each failure names plan, key and value."""

    def __init__(self, source: str, plan_dir: Path, layout=None) -> None:
        from droid.experiments.trial import ARM_MODELS, SENSOR_MODELS
        from droid.brain.cell.cell_layout import load_layout

        self.source = source
        self.plan_dir = plan_dir
        self.layout = layout if layout is not None else load_layout()  # the plan cell's, else the bundled
        self.arms = ARM_MODELS
        self.sensors = SENSOR_MODELS
        self._workpieces: dict[str, str] = {}

    def bad(self, where: str, key: str, value, why: str) -> BadInput:
        return BadInput(f"plan {self.source}: {where}{key} = {_toml(value)}: {why}")

    def text(self, where: str, key: str, value, what: str) -> str:
        """``value`` if it is a non-empty string, else bad: ``what`` says what it must be."""
        if not isinstance(value, str) or not value:
            raise self.bad(where, key, value, what)
        return value

    def check(self, where: str, key: str, value):
        """The value, normalised (ints of float keys become floats; workpiece paths resolved)."""
        def is_num(v) -> bool:
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

        def is_int(v) -> bool:
            return isinstance(v, int) and not isinstance(v, bool)

        def choice(options) -> str:
            if not isinstance(value, str):
                raise self.bad(where, key, value, "must be a string")
            if value not in options:
                raise self.bad(where, key, value, f"unknown (known: {', '.join(options)})")
            return value

        if key in ("speed_mm_s", "length_mm"):
            if not is_num(value):
                raise self.bad(where, key, value, "must be a finite number")
            if value <= 0:
                raise self.bad(where, key, value, "must be > 0")
            hi, unit = (MAX_RUN_LENGTH_MM, "mm") if key == "length_mm" else (MAX_SPEED_MM_S, "mm/s")
            if value > hi:
                raise self.bad(where, key, value, f"must be <= {hi:g} {unit}")
            return float(value)
        if key in ("yaw_gain", "pitch_gain", "delay_at_mm"):
            if not is_num(value):
                raise self.bad(where, key, value, "must be a finite number")
            hi = MAX_RUN_LENGTH_MM if key == "delay_at_mm" else MAX_GAIN  # droid-seamtrack's ranges
            if not 0 <= value <= hi:
                raise self.bad(where, key, value, f"must be within [0, {hi:g}]")
            return float(value)
        if key in ("delay_cycles", "seed"):
            if not is_int(value):
                raise self.bad(where, key, value, "must be an integer")
            hi = MAX_CYCLES if key == "delay_cycles" else 2 ** 31 - 1
            if value < 0 or value > hi:
                raise self.bad(where, key, value, f"must be within [0, {hi}]")
            return int(value)
        if key == "position":
            return choice(list(self.layout.positions))
        if key == "wrist":
            return choice(sorted(self.layout.wrists))
        if key == "arm":
            return choice(self.arms)
        if key == "sensor":
            return choice(self.sensors)
        if key == "mode":
            self.text(where, key, value, "must be a non-empty string")
            if "mode" not in _trial_config_fields():
                raise self.bad(where, key, value, "this droid's TrialConfig has no tracking mode "
                                                  "(a newer droid-experiment is needed)")
            return value
        if key == "workpiece":
            return self.workpiece(where, self.text(where, key, value, "must be a bundled workpiece name or a path"))
        raise AssertionError(key)

    def resolved(self, value: str | None) -> str | None:
        """The spec load_workpiece takes for a checked workpiece value (a path made absolute)."""
        return None if value is None else self._workpieces[value]

    def workpiece(self, where: str, value: str) -> str:
        """Check a workpiece (a bundled name, or a path relative to the plan) by loading it.

        Returns the value as written (the trial's parameter, hashed into its
        ID); :meth:`resolved` gives the spec the trial loads."""
        if value in self._workpieces:
            return value
        from droid.sim.workpiece import WORKPIECE_DIR, load_workpiece

        is_path = os.sep in value or value.endswith(".toml")
        if is_path:
            path = Path(value) if os.path.isabs(value) else self.plan_dir / value
            if not path.is_file():
                raise self.bad(where, "workpiece", value, f"file not found ({path})")
            spec = str(path.resolve())
        else:
            if not (WORKPIECE_DIR / f"{value}.toml").is_file():
                from droid.sim.workpiece import bundled_workpieces

                raise self.bad(where, "workpiece", value,
                               f"no such bundled workpiece (bundled: {', '.join(bundled_workpieces())})")
            spec = value
        try:
            load_workpiece(spec)
        except BadInput as exc:
            raise self.bad(where, "workpiece", value, str(exc)) from None
        self._workpieces[value] = spec
        return value


def _toml(value) -> str:
    """A value as the plan wrote it (TOML-ish: strings quoted, lists bracketed)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{...}"
    return str(value)


def load_plan(spec: str | os.PathLike) -> Plan:
    """Read and validate a plan (a path or a bundled plan's name); BadInput names plan, key and value."""
    path = resolve_plan_path(os.fspath(spec))
    source = str(path)
    return plan_from_dict(read_toml(path, "plan"), source, path.resolve().parent)


def plan_from_dict(data: dict, source: str = "<plan>", plan_dir: Path | None = None) -> Plan:
    """Validate a parsed plan and expand its trials (see the module docstring)."""
    name, description, kind = _plan_head(data, source)
    cell = _plan_cell(data, kind, source, plan_dir or Path.cwd())
    checker = _Checker(source, plan_dir or Path.cwd(), cell.layout if cell is not None else None)
    keys = _PlanKeys(source, kind, checker)
    defaults = keys.defaults_table(data.get("defaults", {}))
    sweep = keys.sweep_table(data.get("sweep", {}), defaults)
    keys.check_builtin(defaults, sweep)
    trials = keys.expand(data, name, cell, defaults, sweep)
    return Plan(name, description, source, defaults, sweep, tuple(trials), kind)


def _bad(source: str, msg: str) -> BadInput:
    return BadInput(f"plan {source}: {msg}")


def _plan_head(data: dict, source: str) -> tuple[str, str, str]:
    """The plan's top-level keys checked: its name, description and trial kind; every number in
    its range; ``[defaults]`` and ``[sweep]`` tables."""
    for key in data:
        if key not in _TOP_KEYS:
            raise _bad(source, f"{key} = {_toml(data[key])}: unknown key (expected one of {', '.join(_TOP_KEYS)})")
    try:
        check_numbers(data)  # every number finite and inside its key's range (issue 16)
    except NumberError as exc:
        raise _bad(source, str(exc)) from None
    name = data.get("name")
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise _bad(source, f"name = {_toml(name) if name is not None else '(missing)'}: needs a name of letters, "
                           "digits, _ . - (the output directory)")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise _bad(source, f"description = {_toml(description)}: must be a string")
    kind = data.get("trial", TRIAL_SEAMTRACK)
    if kind not in TRIAL_KINDS:
        raise _bad(source, f"trial = {_toml(kind)}: unknown trial (known: {', '.join(TRIAL_KINDS)})")
    for table in ("defaults", "sweep"):
        raw = data.get(table, {})
        if not isinstance(raw, dict):
            raise _bad(source, f"{table} = {_toml(raw)}: must be a table [{table}]")
    return name, description, kind


class _PlanKeys:
    """The keys of one kind of plan's ``[defaults]`` and ``[sweep]``: their checks, the built-in
    defaults, and the expansion of the sweep into trials (seam-tracking: :data:`FIELDS`;
    contact: droid.experiments.contact_plan)."""

    def __init__(self, source: str, kind: str, checker: _Checker) -> None:
        self.source, self.kind, self.checker = source, kind, checker
        if kind == TRIAL_SEAMTRACK:
            self.keys_of, self.builtin, self.check = FIELDS, BUILTIN_DEFAULTS, checker.check
        else:
            from droid.experiments.contact_plan import ContactKeys

            self.contact = ContactKeys(checker)
            self.keys_of, self.builtin, self.check = self.contact.fields, self.contact.defaults, self.contact.check

    def bad(self, msg: str) -> BadInput:
        return _bad(self.source, msg)

    def unknown(self, where: str, key: str, value) -> BadInput:
        kind, keys_of = self.kind, self.keys_of
        if kind != TRIAL_SEAMTRACK and key in FIELDS:
            return self.bad(f"{where} {key} = {_toml(value)}: a seam-tracking key, not one of a {kind} plan "
                            f"(its keys: {', '.join(keys_of)})")
        hint = ""
        if kind == TRIAL_SEAMTRACK:
            from droid.experiments.contact_plan import CONTACT_FIELDS

            if key in CONTACT_FIELDS:
                hint = '; a contact plan\'s key: set trial = "contact"'
        return self.bad(f"{where} {key} = {_toml(value)}: unknown key (expected one of {', '.join(keys_of)}){hint}")

    def defaults_table(self, defaults_raw: dict) -> dict:
        """``[defaults]``, every value checked."""
        defaults: dict = {}
        for key, value in defaults_raw.items():
            if key not in self.keys_of:
                raise self.unknown("[defaults]", key, value)
            defaults[key] = self.check("[defaults] ", key, value)
        return defaults

    def sweep_table(self, sweep_raw: dict, defaults: dict) -> dict:
        """``[sweep]``: a non-empty list of distinct checked values per key, none also in ``[defaults]``."""
        sweep: dict = {}
        for key, values in sweep_raw.items():
            if key not in self.keys_of:
                raise self.unknown("[sweep]", key, values)
            if key in defaults:
                raise self.bad(f"[sweep] {key} = {_toml(values)}: also set in [defaults] (give it in one of them)")
            if not isinstance(values, list):
                raise self.bad(f"[sweep] {key} = {_toml(values)}: must be a list of values")
            if not values:
                raise self.bad(f"[sweep] {key} = []: empty list (give at least one value)")
            checked = [self.check("[sweep] ", key, v) for v in values]
            seen = set()
            for raw_v, v in zip(values, checked):
                if v in seen:
                    raise self.bad(f"[sweep] {key} = {_toml(values)}: {_toml(raw_v)} appears twice")
                seen.add(v)
            sweep[key] = checked
        return sweep

    def check_builtin(self, defaults: dict, sweep: dict) -> None:
        """A contact plan: a builtin default's checks too (its workpiece is loaded, its gains read)."""
        if self.kind != TRIAL_SEAMTRACK:
            for key, value in self.builtin.items():
                if key not in defaults and key not in sweep and value is not None:
                    self.check("(default) ", key, value)

    def expand(self, data: dict, name: str, cell, defaults: dict, sweep: dict) -> list[PlanTrial]:
        """The trials: the product of the ``[sweep]`` lists over ``[defaults]`` and the builtin
        defaults, each with its ID and its checked config."""
        kind, keys_of = self.kind, self.keys_of

        def where_of(key: str) -> str:
            return "[sweep] " if key in sweep else "[defaults] " if key in defaults else "(default) "

        base = {**self.builtin, **defaults}
        trials = []
        ids: set[str] = set()
        checked: set[tuple] = set()  # (arm, holder) models the plan's cell was checked for
        keys = list(sweep)
        for index, combo in enumerate(itertools.product(*(sweep[k] for k in keys))):
            params = {**base, **dict(zip(keys, combo))}
            params = {k: params[k] for k in keys_of}
            if cell is not None:  # as written: the trial's ID says which cell it ran on
                params["cell"] = data["cell"]
            tid = trial_id(params)
            if tid in ids:  # a hash collision within one plan: 10 hex digits make this ~1e-9 at 10^3 trials
                raise self.bad(f"two trials have the same ID {tid}")
            ids.add(tid)
            if kind != TRIAL_SEAMTRACK:
                config = self.contact.config(tid, params, where_of)  # its BadInput names the key (and plan) itself
            else:
                resolved = {"workpiece": self.checker.resolved(params["workpiece"]), **_cell_param(cell)}
                try:
                    config = trial_config(tid, {**params, **resolved}, name)
                except BadInput as exc:  # TrialConfig's own checks (e.g. a mode it does not know)
                    shown = ", ".join(f"{k} = {_toml(params[k])}" for k in keys)
                    raise self.bad(f"trial {index} ({shown}): {exc}") from None
                _check_cell_for(cell, config, self.source, checked)
            trials.append(PlanTrial(tid, index, params, config, name, kind))
        return trials


def _plan_cell(data: dict, kind: str, source: str, plan_dir: Path):
    """The plan's ``cell`` key as a checked trial_cell.TrialCell (for the full arm and the GMF1;
    each trial's models are checked as its config is made), or None without one."""
    if "cell" not in data:
        return None
    value = data["cell"]
    if kind != TRIAL_SEAMTRACK:
        raise BadInput(f"plan {source}: cell = {_toml(value)}: applies to seam-tracking plans only")
    if not isinstance(value, str) or not value:
        raise BadInput(f"plan {source}: cell = {_toml(value)}: must be a cell file's path or a bundled cell's name")
    from droid.sim.trial_cell import resolve_cell_path, resolve_trial_cell

    try:
        return resolve_trial_cell(resolve_cell_path(value, plan_dir), "full", "gmf1")
    except BadInput as exc:
        raise BadInput(f"plan {source}: cell = {_toml(value)}: {exc}") from None


def _cell_param(cell) -> dict:
    """TrialConfig's ``cell`` (the resolved path) of a plan with a cell, else nothing."""
    return {} if cell is None else {"cell": str(cell.cell.path)}


def _check_cell_for(cell, config, source: str, checked: set) -> None:
    """The plan's cell checked for a trial's arm and holder models (once a pair, kept in ``checked``)."""
    if cell is None or (config.arm, config.holder) in checked:
        return
    from droid.sim.trial_cell import resolve_trial_cell

    checked.add((config.arm, config.holder))
    try:
        resolve_trial_cell(cell.cell, config.arm, config.holder, cell.layout)
    except BadInput as exc:
        raise BadInput(f"plan {source}: cell: {exc}") from None


def trial_config(tid: str, params: dict, plan_name: str = ""):
    """The TrialConfig of a plan trial (``mode`` passed only when set)."""
    from droid.experiments.trial import TrialConfig

    kw = {k: v for k, v in params.items() if not (k == "mode" and v is None)}
    piece = f", {Path(params['workpiece']).stem}" if params.get("workpiece") else ""
    title = f"{plan_name} {tid}: {_show(params['speed_mm_s'])} mm/s, position {params['position']}{piece}"
    return TrialConfig(trial_id=tid, title=title, **kw)
