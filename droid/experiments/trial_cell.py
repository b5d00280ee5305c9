"""A lockstep trial on a cell file: ``TrialConfig.cell``, ``droid-experiment run --cell FILE``, a plan's ``cell``.

The trial reads the cell's seam-tracking layout (its ``[cell] layout``, else the bundled one:
droid.brain.cell_layout.layout_for_cell); the welder is the layout's ``tool_robot``, the holder
its ``holder_robot``, both subunits of the cell at the cell's bases with the layout's robot
files.  Both are chosen through the registry: the builder its device package registers in the
``lockstep`` slot (droid.sim.lockstep_cell.choose_builder, by the programs the subunit runs), which
must stand for no program the subunit does not run (the builder's own ``@builds``):

* the welder's, one of :func:`welder_builders` -- the ABB on EGM
  (:class:`droid.sim.abb.lockstep.LockstepAbbArm`, its ``abb_egm`` world device: its controller)
  or the Reis (:class:`droid.sim.reis.cell.LockstepArm`);
* the holder's (``holder = "gmf1"``), :func:`holder_builder`: the GMF1's;
* anything else: one line naming the file, the subunit and what a lockstep arm needs.

Both are built by those builders (:func:`welder_lockstep`, :func:`holder_lockstep`) with the
trial's seed, the cell's ``stale_ticks`` and the trial's own world (:func:`trial_world`) instead
of the cell's world-device tables.  A trial without a cell file runs on the built-in cell
(droid/cells/sim.toml, whatever $DROID_CELL says; :func:`builtin_trial_cell`): the Reis ``arm1``
and the GMF1 ``gmf1``.

The ``fast`` arm model is the Reis's (calibrated against its servo and plant,
droid.experiments.arm_fast): a welder that is not a Reis with ``arm = "fast"`` is refused.  The
holder is the GMF1 with the cell's serial and encoder set-up (droid.experiments.holder).  The trial runs at the heartbeat of
droid.brain.device.HEARTBEAT_HZ (its 30 Hz cycle is 2 ticks): a cell of another rate is refused.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

from droid.brain.cellfile import BUNDLED_CELLS, Cell, builtin_cell_path, find_file, load_cell
from droid.brain.device import HEARTBEAT_HZ
from droid.brain.wire import LIVENESS_TICKS
from droid.cli import BadInput
from droid.brain.cell_layout import Layout, check_bases, layout_for_cell



def welder_builders() -> dict:
    """The lockstep builders whose arm the ``full`` model drives (an ArmChain with the world's
    ``wcp_global``), by what the trial calls them: the Reis's (droid.sim.reis.cell) and the ABB's
    on EGM (droid.sim.abb.lockstep).  What their subunits run is the builders' own ``@builds``."""
    from droid.sim.abb.lockstep import build as abb
    from droid.sim.reis.cell import build as reis

    return {reis: "the Reis", abb: "the ABB"}


def holder_builder():
    """The lockstep builder of the ``gmf1`` holder model's subunit (droid.sim.gmf1.lockstep): the
    trial's Gmf1Holder steps the same cores (droid.experiments.holder)."""
    from droid.sim.gmf1.lockstep import build

    return build


@dataclass(frozen=True)
class TrialCell:
    """A checked cell of a trial: the cell, its layout and its welder's lockstep builder."""

    cell: Cell
    layout: Layout
    welder: object  # its tool_robot's lockstep builder (one of welder_builders())

    @property
    def reis(self) -> bool:
        """Whether the welder is the Reis (the ``fast`` arm model's)."""
        return welder_builders()[self.welder] == "the Reis"


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


def _whole_builder(cell: Cell, layout: Layout, role: str, what: str, builders: dict):
    """The lockstep builder of the layout's ``role`` subunit: the one lockstep_cell.choose_builder
    picks (by the programs the subunit runs), which must be one of ``builders`` (builder -> what
    the trial calls it) and stand for no program the subunit does not run (the trial needs every
    station of its arm); BadInput, one line naming the file, the subunit and what is missing."""
    from droid.sim.lockstep_cell import choose_builder

    sub = _subunit(cell, layout, role)
    where = f"{cell.path}: [subunits.{sub.name}] (the layout's {role})"
    if not sub.is_arm:
        raise BadInput(f"{where} is a {sub.cls} subunit, not an arm: it has no lockstep {what}")
    try:
        build = choose_builder(cell, sub)
    except BadInput:
        build = None
    if build in builders and set(build.programs) <= set(sub.programs):
        getattr(build, "check", lambda c, s: None)(cell, sub)  # what the builder refuses (the ABB: no controller twin), before anything runs
        return build
    runs = ", ".join(sub.programs) or "no programs"
    needs = " or ".join(f"{' + '.join(b.programs)} ({name})" for b, name in builders.items())
    raise BadInput(f"{where} has no lockstep {what}: it runs {runs}; a lockstep {what} needs {needs}")


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
    tc = TrialCell(cell, layout, _whole_builder(cell, layout, "tool_robot", "arm", welder_builders()))
    if holder == "gmf1":
        _whole_builder(cell, layout, "holder_robot", "holder", {holder_builder(): "the GMF1"})
    else:
        _subunit(cell, layout, "holder_robot")
    check_bases(layout, cell)
    _check_robots(cell, layout)
    if arm_model == "fast" and not tc.reis:
        raise BadInput(f"{cell.path}: [subunits.{layout.tool_robot}] is not a Reis: the fast arm model is "
                       f"the Reis's (calibrated against its servo); use the full model (--arm full)")
    return tc


def load_trial_cell(path: str | os.PathLike, arm_model: str = "full", holder: str = "gmf1") -> TrialCell:
    """Read a cell file and its layout and check them for a trial (:func:`check_trial_cell`)."""
    cell = load_cell(path)
    return check_trial_cell(cell, layout_for_cell(cell), arm_model, holder)


def builtin_trial_cell(arm_model: str = "full", holder: str = "gmf1") -> TrialCell:
    """The cell of a trial without a cell file: the built-in cell (droid/cells/sim.toml, whatever
    $DROID_CELL says) with the cell file's default ``stale_ticks`` (LIVENESS_TICKS, the thesis's 3)
    for its 12 -- the arms such a trial always ran: sim.toml's 12 is set against this host's
    real-time stalls, which virtual time has none of, and a fault's order in the Status (a dead
    servo: the servo agent's fault before the watchdog's) follows it."""
    cell = replace(load_cell(builtin_cell_path()), stale_ticks=LIVENESS_TICKS)
    return check_trial_cell(cell, layout_for_cell(cell), arm_model, holder)


def trial_world(tc: TrialCell) -> dict:
    """The trial's own ``[world]`` table, which its subunits' builders read instead of the cell's
    (droid.sim.lockstep_build.BuildContext.world): no world device for the welder -- a Reis
    without world errors or contacts, the arm the ``full`` model always ran (the ABB's builder
    reads its ``abb_egm`` controller twin from the cell) -- and the holder's twin
    (droid.experiments.holder.holder_device) stepped at the holder's world rate."""
    from droid.experiments.holder import WORLD_HZ, holder_device

    return {"rate_hz": WORLD_HZ, "devices": {"trial_holder": holder_device(tc.layout.holder_robot)}}


def _built(sched, tc: TrialCell, name: str, seed: int):
    from droid.sim.lockstep_cell import build_subunits

    return build_subunits(sched, tc.cell, [name], seed, world=trial_world(tc))[name]


def welder_lockstep(sched, tc: TrialCell, seed: int):
    """The welder's lockstep arm on ``sched`` (an ArmChain: LockstepArm or LockstepAbbArm), built
    by its package's builder (lockstep_cell.build_subunits) in the trial's world
    (:func:`trial_world`) with the trial's ``seed`` and the cell's ``stale_ticks``."""
    return _built(sched, tc, tc.layout.tool_robot, seed).arm


def holder_lockstep(sched, tc: TrialCell, seed: int):
    """The holder's Gmf1Lockstep on ``sched``, built by the GMF1 package's builder in the trial's
    world (:func:`trial_world`) with the trial's ``seed``."""
    return _built(sched, tc, tc.layout.holder_robot, seed).parts
