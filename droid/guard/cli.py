"""droid-guard: the cell-level collision guard between the arms (issue 41; docs/guard.md).

Usage::

    droid-guard check [--cell FILE] [--json] ARM=Q1,Q2,Q3,Q4,Q5,Q6 ...
    droid-guard [run] [--cell FILE] [--seconds S]

``check`` prints the least distance [mm] between the cell's bodies (every pair of bodies of
two different arms and every arm body against every fixture, less the ``[guard] allow``
pairs) for one joint vector [deg] of every arm, and the closest pair::

    min 473.1 mm: gmf1 link 4 with arm1 sensor

(``--json``: ``{"distance_mm": ..., "a": "gmf1.link_4", "b": "arm1.sensor", "in_collision": false,
"pairs": N}``).  A distance <= 0 is a collision (``... in collision``).  Every arm of the cell
must be given.  Bad input (an unknown arm, a joint vector that is not six finite numbers, an
``allow`` pair naming an unknown arm or body) is one line on stderr, exit 2.

``run`` is the live guard (:mod:`droid.guard.live`): on a cell that is up, every heartbeat
tick it reads every arm's Brain Status, runs the guard's cycle, sets FAULT_COLLISION in every
arm's own Status on a protective stop, writes its tick and each arm's speed override into the
arm's Brain Command and its own Status into ``/droid.<cell>.guard.status`` (``droid-snoop
guard``).  ``droid-cell up`` starts it (``droid-guard --cell FILE``: no sub-command is ``run``)
where the cell declares a ``[guard]`` table (docs/guard.md).
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Sequence

import numpy as np

from droid.brain.cell.cellfile import load_cell
from droid.cli import ArgumentParser, BadInput, bounded_float, bounded_int, parse_finite, run
from droid.guard.cell import guard_scene

PROG = "droid-guard"
MAX_RUN_S = 86400.0 * 365  # --seconds: at most a year


def _parser() -> ArgumentParser:
    ap = ArgumentParser(prog=PROG, description="the cell-level collision guard between the arms (docs/guard.md)")
    sub = ap.add_subparsers(dest="cmd", required=True)
    ck = sub.add_parser("check", help="the least distance between the cell's bodies and its pair")
    ck.add_argument("--cell", default=None, help="cell file (default: $DROID_CELL or the built-in sim cell)")
    ck.add_argument("--json", action="store_true", help="one JSON record")
    ck.add_argument("joints", nargs="*", metavar="ARM=Q1,...,Q6", help="an arm's joint vector [deg]")
    rn = sub.add_parser("run", help="the live guard on a cell that is up (docs/guard.md)")
    rn.add_argument("--cell", default=None, help="cell file (default: $DROID_CELL or the built-in sim cell)")
    rn.add_argument("--ready-fd", type=bounded_int(0, 1 << 20), default=None, help=argparse.SUPPRESS)
    rn.add_argument("--seconds", type=bounded_float(0.0, MAX_RUN_S, "s", lo_open=True), default=None, metavar="S",
                    help="stop after S seconds (default: until SIGINT/SIGTERM)")
    return ap


def parse_joints(items: Sequence[str], arms: Sequence[str]) -> dict[str, np.ndarray]:
    """``ARM=Q1,...,Q6`` [deg] for every arm -> {arm: (6,)}; :class:`BadInput` (one line) otherwise."""
    out: dict[str, np.ndarray] = {}
    for item in items:
        name, eq, values = item.partition("=")
        if not eq:
            raise BadInput(f"check: {item!r}: expected ARM=Q1,Q2,Q3,Q4,Q5,Q6 (deg)")
        if name not in arms:
            raise BadInput(f"check: unknown arm {name!r} (arms: {', '.join(arms)})")
        parts = values.split(",")
        if len(parts) != 6:
            raise BadInput(f"check: {name}: expected 6 joint angles (deg), got {len(parts)}")
        try:
            out[name] = np.array([parse_finite(v.strip()) for v in parts])
        except ValueError as exc:
            raise BadInput(f"check: {name}: {exc}") from None
    missing = [a for a in arms if a not in out]
    if missing:
        raise BadInput(f"check: no joint vector for arm(s) {', '.join(missing)} (give ARM=Q1,...,Q6 for every arm)")
    return out


@run
def main(argv: Sequence[str] | None = None) -> int:
    """droid-guard entry point (see module docstring)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in ("check", "run", "-h", "--help", "--version"):
        argv.insert(0, "run")  # as droid-cell up starts it: droid-guard --cell FILE --ready-fd N
    args = _parser().parse_args(argv)
    if args.cmd == "run":
        from droid.guard.live import run_live

        return run_live(args.cell, args.seconds, args.ready_fd)
    scene = guard_scene(load_cell(args.cell))
    q = parse_joints(args.joints, list(scene.arms))
    c = scene.closest(q)
    if args.json:
        print(json.dumps({**c.as_dict(), "pairs": scene.n_pairs}))
    else:
        tail = " (in collision)" if c.in_collision else ""
        print(f"min {c.distance_mm:.1f} mm: {c.a.label()} with {c.b.label()}{tail}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
