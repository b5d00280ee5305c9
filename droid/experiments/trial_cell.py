"""A lockstep trial on a cell file: ``TrialConfig.cell``, ``droid-experiment run --cell FILE``, a plan's ``cell``.

The trial reads the cell's seam-tracking layout (its ``[cell] layout``, else the bundled one:
droid.brain.cell_layout.layout_for_cell); the welder is the layout's ``tool_robot``, the holder
its ``holder_robot``, both subunits of the cell at the cell's bases with the layout's robot
files.  The welder's lockstep arm is chosen by what its subunit runs:

* ``droid-egm`` (with ``droid-planner``): the ABB on EGM, :class:`droid.sim.abb.lockstep.LockstepAbbArm`
  (its ``abb_egm`` world device, the cell's ``stale_ticks``);
* the Reis set (``droid-servo``, ``droid-servo-agent``, ``droid-planner``):
  :class:`droid.sim.reis.cell.LockstepArm`, built as the ``full`` arm model builds it (the
  subunit's name, robot file and base, the trial's seed; no world errors), with the cell's
  ``stale_ticks``;
* anything else has no lockstep: one line naming the file, the subunit and what is missing.

The ``fast`` arm model is the Reis's (calibrated against its servo and plant,
droid.experiments.arm_fast): a welder that is not a Reis with ``arm = "fast"`` is refused.  The
holder is the GMF1 (``droid-gmf1-serial``, ``droid-gmf1-encoder``) with the cell's serial and
encoder set-up (droid.experiments.holder).  The trial runs at the heartbeat of
droid.brain.device.HEARTBEAT_HZ (its 30 Hz cycle is 2 ticks): a cell of another rate is refused.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from droid.brain.cellfile import BUNDLED_CELLS, Cell, find_file, load_cell
from droid.brain.device import HEARTBEAT_HZ
from droid.cli import BadInput
from droid.brain.cell_layout import Layout, check_bases, layout_for_cell

#: the programs the Reis's lockstep arm stands for (droid.sim.reis.cell)
REIS_PROGRAMS = ("droid-servo", "droid-servo-agent", "droid-planner")
#: the programs the ABB's lockstep arm stands for (droid.sim.abb.lockstep)
EGM_PROGRAMS = ("droid-egm", "droid-planner")
#: the programs the GMF1 holder's lockstep stands for (droid.sim.gmf1.lockstep)
GMF1_PROGRAMS = ("droid-gmf1-serial", "droid-gmf1-encoder")
WELDER_REIS, WELDER_ABB = "reis", "abb"


@dataclass(frozen=True)
class TrialCell:
    """A checked cell of a trial: the cell, its layout and the kind of its welder."""

    cell: Cell
    layout: Layout
    welder: str  # WELDER_REIS or WELDER_ABB


def bundled_cells() -> list[str]:
    return sorted(p.name for p in BUNDLED_CELLS.glob("*.toml") if "layout" not in p.name)


def resolve_cell_path(spec: str, base_dir: str | os.PathLike | None = None) -> Path:
    """A cell file by path (relative to ``base_dir``, default the working directory), or by the
    bare name of a bundled cell (``abb_weld.toml``, ``abb_weld``).  BadInput when there is none."""
    found = find_file(spec, Path(base_dir) if base_dir is not None else Path.cwd(), ".toml")
    if found is None:
        raise BadInput(f"cell file not found: {spec} (bundled cells: {', '.join(bundled_cells())})")
    return found


def _subunit(cell: Cell, layout: Layout, role: str):
    name = getattr(layout, role)
    if name not in cell.subunits:
        raise BadInput(f"{cell.path}: its layout {layout.source} names {role} {name!r}, a subunit the cell "
                       f"does not have (its subunits: {', '.join(sorted(cell.subunits))})")
    return cell.subunit(name)


def welder_kind(cell: Cell, layout: Layout) -> str:
    """:data:`WELDER_ABB` or :data:`WELDER_REIS` by the programs the tool robot's subunit runs."""
    sub = _subunit(cell, layout, "tool_robot")
    where = f"{cell.path}: [subunits.{sub.name}] (the layout's tool_robot)"
    if not sub.is_arm:
        raise BadInput(f"{where} is a {sub.cls} subunit, not an arm: it has no lockstep arm")
    progs = set(sub.programs)
    if all(p in progs for p in EGM_PROGRAMS):
        from droid.sim.abb.lockstep import egm_device

        egm_device(cell, sub.name)  # its controller twin, or one line
        return WELDER_ABB
    if all(p in progs for p in REIS_PROGRAMS):
        return WELDER_REIS
    runs = ", ".join(sub.programs) or "no programs"
    raise BadInput(f"{where} has no lockstep arm: it runs {runs}; a lockstep arm needs "
                   f"{' + '.join(EGM_PROGRAMS)} (the ABB) or {' + '.join(REIS_PROGRAMS)} (the Reis)")


def check_holder(cell: Cell, layout: Layout) -> None:
    sub = _subunit(cell, layout, "holder_robot")
    if not sub.is_arm or not all(p in sub.programs for p in GMF1_PROGRAMS):
        runs = ", ".join(sub.programs) or "no programs"
        raise BadInput(f"{cell.path}: [subunits.{sub.name}] (the layout's holder_robot) has no lockstep "
                       f"holder: it runs {runs}; the GMF1's needs {' + '.join(GMF1_PROGRAMS)}")


def _check_robots(cell: Cell, layout: Layout) -> None:
    for name in (layout.tool_robot, layout.holder_robot):
        robot, sub = layout.robots.get(name), cell.subunit(name)
        if robot is not None and robot != sub.robot:
            raise BadInput(f"{cell.path}: [subunits.{name}] robot {sub.robot!r} differs from its layout "
                           f"{layout.source}'s {robot!r}: one arm, one robot file")


def check_trial_cell(cell: Cell, layout: Layout, arm_model: str = "full", holder: str = "gmf1") -> TrialCell:
    """Everything a trial on ``cell`` needs, checked before anything runs (see the module
    docstring); BadInput, one line, otherwise."""
    if cell.heartbeat_hz != HEARTBEAT_HZ:
        raise BadInput(f"{cell.path}: heartbeat_hz {cell.heartbeat_hz:g}: the lockstep trial runs at "
                       f"{HEARTBEAT_HZ:g} Hz (its 30 Hz tracking cycle is 2 ticks)")
    welder = welder_kind(cell, layout)
    if holder == "gmf1":
        check_holder(cell, layout)
    else:
        _subunit(cell, layout, "holder_robot")
    check_bases(layout, cell)
    _check_robots(cell, layout)
    if arm_model == "fast" and welder != WELDER_REIS:
        raise BadInput(f"{cell.path}: [subunits.{layout.tool_robot}] is not a Reis: the fast arm model is "
                       f"the Reis's (calibrated against its servo); use the full model (--arm full)")
    return TrialCell(cell, layout, welder)


def load_trial_cell(path: str | os.PathLike, arm_model: str = "full", holder: str = "gmf1") -> TrialCell:
    """Read a cell file and its layout and check them for a trial (:func:`check_trial_cell`)."""
    cell = load_cell(path)
    return check_trial_cell(cell, layout_for_cell(cell), arm_model, holder)


def welder_lockstep(sched, tc: TrialCell, seed: int):
    """The welder's lockstep arm on ``sched`` (an ArmChain: LockstepAbbArm or LockstepArm)."""
    sub = tc.cell.subunit(tc.layout.tool_robot)
    if tc.welder == WELDER_ABB:
        from droid.sim.abb.lockstep import LockstepAbbArm

        return LockstepAbbArm(sched, tc.cell, sub.name)
    from droid.sim.reis.cell import LockstepArm

    return LockstepArm(sched, sub.name, robot=sub.robot, base=tuple(sub.base), seed=seed,
                       stale_ticks=tc.cell.stale_ticks)
