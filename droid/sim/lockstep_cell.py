"""A whole cell file in lockstep: every subunit of every class on one scheduler (docs/design.md §2, §11).

:func:`build_lockstep_cell` reads the same cell file ``droid-cell up`` reads and puts every
subunit on one :class:`~droid.sim.lockstep.Scheduler` at the cell's heartbeat (thesis §3.2),
each through the builder its device package registers in the registry's ``lockstep`` slot
(:mod:`droid.sim.lockstep_build`): arms first (a sensor finds the arm it sits on or looks at),
then the others, in the file's order.  Every subunit's builder is chosen and checked before
anything is built: an unknown class, a class no package builds in lockstep, a program no
builder has a station for is one line ``FILE: [subunits.NAME] ...`` (BadInput, exit 2).

``droid-sim lockstep CELL --seconds S [--json]`` (:func:`lockstep_main`) builds a cell, runs S
virtual seconds and prints each subunit's Status summary.
"""
from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from typing import Callable

import numpy as np

from droid.brain.cell.cellfile import Cell, load_cell
from droid.cli import BadInput
from droid.sim.lockstep import Scheduler
from droid.sim.lockstep_build import BuildContext, LockstepSubunit


def choose_builder(cell: Cell, sub) -> Callable:
    """The lockstep builder of ``sub`` (see the module docstring of droid.sim.lockstep_build):
    of the packages serving its class, the first whose builder stands for every program the
    subunit runs, preferring one that stands for any of them.  BadInput, one line, otherwise."""
    where = f"{cell.path}: [subunits.{sub.name}]"
    builders = class_builders(cell, sub)
    need = set(sub.programs)
    fits = [b for _, b in builders if need <= set(b.programs)]
    if fits:
        return next((b for b in fits if need & set(b.programs)), fits[0])
    stood = set().union(*(b.programs for _, b in builders))
    missing = [p for p in sub.programs if p not in stood]
    if missing:
        raise BadInput(f"{where} program {missing[0]!r} has no lockstep station (the lockstep builders of "
                       f"class {sub.cls!r} stand for {', '.join(sorted(stood))})")
    raise BadInput(f"{where} no one lockstep builder stands for all its programs ({', '.join(sub.programs)}): "
                   + "; ".join(f"{n}: {', '.join(b.programs)}" for n, b in builders))


def class_builders(cell: Cell, sub) -> list[tuple[str, Callable]]:
    """(package name, lockstep builder) of every package serving ``sub``'s class that registers
    one, in the registry's order; BadInput, one line, for an unknown class or one without any."""
    from droid.brain.cell.registry import registry

    reg = registry()
    where = f"{cell.path}: [subunits.{sub.name}]"
    if sub.cls not in reg.classes:
        raise BadInput(f"{where} class: {reg.unknown('class', sub.cls, reg.classes)}")
    pkgs = [p for p in reg.package_of_class(sub.cls) if not p.generic]
    builders = [(p.name, _builder(reg, p, where)) for p in pkgs if p.lockstep]
    if not builders:
        names = ", ".join(repr(p.name) for p in pkgs) or "none"
        raise BadInput(f"{where} class {sub.cls!r} has no lockstep builder (package {names} registers none "
                       f"in its lockstep slot)")
    return builders


def _builder(reg, pkg, where: str) -> Callable:
    """Package ``pkg``'s lockstep builder (imported now); BadInput, one line, when its slot names
    something that does not import or is no builder (no ``@builds`` programs)."""
    from droid.brain.cell.registry import resolve

    try:
        build = resolve(pkg.lockstep)
    except Exception as exc:  # a package's module that fails to import: one line, what is missing
        raise BadInput(f"{where} package {pkg.name!r}: cannot load its lockstep builder {pkg.lockstep}: "
                       f"{type(exc).__name__}: {exc}") from None
    if not callable(build) or not isinstance(getattr(build, "programs", None), tuple):
        raise BadInput(f"{where} package {pkg.name!r}: its lockstep slot {pkg.lockstep} is not a builder "
                       f"(a function declared with droid.sim.lockstep_build.builds)")
    return build


@dataclass
class LockstepCell:
    """A built cell: ``sched``, ``subunits[name]`` (:class:`LockstepSubunit`: Brain ``status`` and
    ``command``, ``stations``, ``arm``), ``cell``; :meth:`run_for` advances virtual time, :meth:`add`
    starts one more of the cell's subunits on the running scheduler (a declared start order)."""

    cell: Cell
    sched: Scheduler
    subunits: dict[str, LockstepSubunit]
    ctx: BuildContext | None = None

    def run_for(self, seconds: float) -> None:
        """Advance every subunit by ``seconds`` [s] of virtual time."""
        self.sched.run_for(seconds)

    def add(self, name: str, build: Callable | None = None) -> LockstepSubunit:
        """Build subunit ``name`` of the cell now, on the running scheduler, with the context the
        others were built with (its seed, its world, the twins and subunits built so far), by
        ``build`` or the builder :func:`choose_builder` picks: it starts ticking from this instant,
        as HAL's ``addf`` adds a function to a running thread.  A task that needs one subunit
        ready before another moves (a seam-tracking trial: the welder homed and at its start
        before the holder's first tick) builds the cell in that order."""
        ctx = self.ctx
        sub = self.cell.subunit(name)
        done = len(ctx.finish)
        _build_all(ctx, [(sub, build if build is not None else choose_builder(self.cell, sub))], done)
        self.subunits[name] = ctx.built[name]
        return ctx.built[name]

    def close(self) -> None:
        for s in self.subunits.values():
            s.close()

    def __enter__(self) -> "LockstepCell":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def build_lockstep_cell(cell_or_path: Cell | str | os.PathLike | None, seed: int | None = None, *,
                        world: dict | None = None, sched: Scheduler | None = None,
                        subunits: dict[str, Callable | None] | None = None) -> LockstepCell:
    """Every subunit of a cell file (a path, a parsed Cell, or None: the default cell) on one
    scheduler at the cell's heartbeat; ``seed``: the world's (default its ``[world] seed``).
    The cell is checked as ``droid-cell up`` checks it (droid.brain.cell.registry.validate_cell) and
    every builder chosen before anything is built (BadInput, one line: nothing built).

    A task that brings a world of its own passes ``world``, a ``[world]`` table its builders read
    instead of the cell's (:class:`~droid.sim.lockstep_build.BuildContext`), ``sched``, its own
    scheduler at the cell's heartbeat, and ``subunits``, the subunits it needs (name -> its
    builder, or None for the one :func:`choose_builder` picks), built in that order; the others it
    may start later (:meth:`LockstepCell.add`)."""
    from droid.brain.cell.registry import validate_cell

    cell = cell_or_path if isinstance(cell_or_path, Cell) else load_cell(cell_or_path)
    validate_cell(cell)  # what droid-cell up refuses, lockstep refuses
    if subunits is None:
        subs = sorted(cell.subunits.values(), key=lambda s: not s.is_arm)  # arms first, stable
        chosen = [(sub, choose_builder(cell, sub)) for sub in subs]
    else:
        chosen = [(cell.subunit(n), b if b is not None else choose_builder(cell, cell.subunit(n)))
                  for n, b in subunits.items()]
    ctx = BuildContext(Scheduler(cell.heartbeat_hz) if sched is None else sched, cell,
                       int(cell.world.get("seed", 0)) if seed is None else seed, world=world)
    _build_all(ctx, chosen)
    return LockstepCell(cell, ctx.sched, {n: ctx.built[n] for n in cell.subunits if n in ctx.built}, ctx)


def _build_all(ctx: BuildContext, chosen, deferred: int = 0) -> None:
    """Build each (subunit, builder) of ``chosen`` into ``ctx.built``, then run what the builders
    deferred (``ctx.after``) from the ``deferred``-th on; on any error close what was built and
    raise it."""
    try:
        for sub, build in chosen:
            ctx.built[sub.name] = build(ctx, sub)
        for fn in ctx.finish[deferred:]:
            fn()
    except BaseException:
        for built in ctx.built.values():
            built.close()
        raise


def status_summary(sub: LockstepSubunit) -> dict:
    """A subunit's Brain Status as plain JSON values: its name, class, ``tick``, ``stale`` and its
    class's snoop fields (droid-snoop's; the 3x3 ``R`` left out)."""
    from droid.brain.cell.registry import classes

    rec = sub.status.read()
    out = {"subunit": sub.name, "class": sub.cls}
    for f in ("tick", "stale", *classes()[sub.cls].snoop_fields):
        if f in rec.dtype.names and f != "R":
            v = np.asarray(rec[f])
            out[f] = v.round(3).tolist() if v.dtype.kind == "f" else v.tolist()
    return out


#: The longest run ``droid-sim lockstep`` takes [s of virtual time]: a day.
MAX_SECONDS = 86400.0


def lockstep_main(argv: list[str], prog: str = "droid-sim lockstep") -> int:
    """``droid-sim lockstep CELL --seconds S [--json] [--seed N]``: build the cell in lockstep, run
    S virtual seconds, print one line a subunit (its Status summary)."""
    from droid.cli import ArgumentParser, bounded_float, seed_int

    ap = ArgumentParser(prog=prog, description="Build every subunit of a cell file in lockstep (one process, "
                        "virtual time), run it and print each subunit's Brain Status.")
    ap.add_argument("cell_file", metavar="CELL", help="the cell file (as droid-cell up reads it)")
    ap.add_argument("--seconds", type=bounded_float(0.0, MAX_SECONDS, "s"), default=1.0, metavar="S",
                    help="virtual seconds to run (default 1)")
    ap.add_argument("--seed", type=seed_int, default=None, help="world seed (default: the cell file's)")
    ap.add_argument("--json", action="store_true", help="one JSON object per subunit, a line each")
    args = ap.parse_args(argv)
    with build_lockstep_cell(args.cell_file, args.seed) as lc:
        lc.run_for(args.seconds)
        for sub in lc.subunits.values():
            row = status_summary(sub)
            if args.json:
                print(json.dumps(row))
            else:
                rest = "  ".join(f"{k}={v}" for k, v in row.items() if k not in ("subunit", "class"))
                print(f"{row['subunit']} ({row['class']}): {rest}")
    sys.stdout.flush()
    return 0
