"""droid-snoop SUBUNIT: print a subunit's Status (thesis §3.4 "The Snoop program").

"It accepts a subunit identifier and echos all status information at a rate of
1Hz via the Standard Output port."  With ``--json`` each sample is one JSON
object on its own line, with the thesis's field names (x, y, z, R,
encoder_pos, encoder_cmd, busy, homed) plus ``tick`` and ``stale``; sensors
also carry ``invalid`` (Table 3.3 uses ``homed`` as the invalid flag); a
joystick ``axes``, ``buttons`` and ``valid``.  Which fields: the subunit's
class (``snoop_fields`` in :mod:`droid.brain.cell.classes`).
Reads the Brain's database only (a task never touches a device, §3.4).

``droid-snoop guard`` (a cell that declares a collision guard and has no subunit of that name):
the guard's own Status (``/droid.<cell>.guard.status``, docs/guard.md) -- the state, the least
distance and its pair, the closing speed and S_p of the pair that decides (the least margin
d - S_p), the override per arm, the cycle time.  In a cell whose live guard is off (``[guard]
run = false``: its Status database is made, no droid-guard runs) one line saying so (``--json``:
``"state": "off"``), exit 0.

Exit: 0 after ``--count`` samples or on SIGINT; 1 if the cell is not up.
"""
from __future__ import annotations

import json
import signal
import sys
import time

from droid.brain.db.databases import open_brain
from droid.brain.cell.classes import field_json
from droid.brain.runtime.program import open_cell, parser
from droid.brain.runtime.rt import PeriodicTimer
from droid.cli import bounded_int, rate_hz, run

PROG = "droid-snoop"


def status_dict(sub, rec) -> dict:
    """The JSON object of one Status sample: subunit, tick, stale, then the class's snoop fields."""
    d = {"subunit": sub.name, "tick": int(rec["tick"]), "stale": bool(rec["stale"])}
    for name in sub.kind.snoop_fields:
        d[name] = field_json(rec, name)
    return d


def status_text(d: dict) -> str:
    flags = " STALE" if d["stale"] else ""
    if "axes" in d:
        axes = " ".join(f"{v:+.2f}" for v in d["axes"][: max(1, d.get("n_axes", 0))])
        pressed = [i for i, b in enumerate(d["buttons"]) if b]
        state = "valid" if d["valid"] else "INVALID"
        return f"{d['subunit']} tick {d['tick']}{flags}  axes [{axes}]  buttons {pressed}  {state}"
    if "force_N" in d:  # a force/torque sensor (ft6)
        f, t = (" ".join(f"{v:+.2f}" for v in d[k]) for k in ("force_N", "torque_Nm"))
        return (f"{d['subunit']} tick {d['tick']}{flags}  F [{f}] N  T [{t}] N m  "
                f"{'valid' if d['valid'] else 'INVALID'}{'  SATURATED' if d['saturated'] else ''}")
    if "invalid" in d:
        state = "INVALID" if d["invalid"] else "valid"
        return (f"{d['subunit']} tick {d['tick']}{flags}  x {d['x']:.3f}  y {d['y']:.3f}  "
                f"z {d['z']:.3f} mm  {state}")
    homed = "homed" if d["homed"] else "not homed"
    fault = f"  fault {','.join(d['fault'])}" if d["fault"] else ""
    enc = " ".join(f"{v}" for v in d["encoder_pos"])
    return (f"{d['subunit']} tick {d['tick']}{flags}  x {d['x']:.2f} y {d['y']:.2f} z {d['z']:.2f} mm  "
            f"enc [{enc}]  busy {d['busy']}  {homed}  {d['cmd_mode']}{fault}")


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Print a subunit's Status record (default once a second).")
    ap.add_argument("subunit", help="subunit name, e.g. arm1")
    ap.add_argument("--rate", type=rate_hz(0.001, 1000.0), default=1.0, metavar="HZ",
                    help="samples per second (default 1)")
    ap.add_argument("--count", type=bounded_int(1, 10**9, "samples"), default=None, metavar="N",
                    help="stop after N samples (default: until interrupted)")
    ap.add_argument("--json", action="store_true", help="one JSON object a line")
    args = ap.parse_args(argv)
    cell = open_cell(args)
    if args.subunit == GUARD and GUARD not in cell.subunits and "guard" in cell.raw:
        return _snoop_guard(cell, args)
    sub = cell.subunit(args.subunit)
    return _print_records(open_brain(cell, sub, "status"), args, lambda rec: status_dict(sub, rec), status_text)


def _print_records(db, args, as_dict, as_text) -> int:
    """droid-snoop's loop: ``--count`` records of ``db`` at ``--rate``, a line each (``--json``:
    the dict), until SIGTERM or Ctrl-C; closes ``db``."""
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    timer = PeriodicTimer(int(round(1e9 / args.rate)), start_ns=time.monotonic_ns())
    n = 0
    try:
        while args.count is None or n < args.count:
            timer.wait()
            d = as_dict(db.read())
            print(json.dumps(d) if args.json else as_text(d), flush=True)
            n += 1
    finally:
        timer.close()
        db.close()
    return 0


GUARD = "guard"


def guard_text(d: dict) -> str:
    """One line of the guard's Status: state, least distance and pair, the deciding pair's closing speed
    and S_p, overrides, cycle time."""
    over = " ".join(f"{a} {v:.2f}" for a, v in d["override"].items())
    return (f"guard tick {d['tick']}  {d['state']}  {d['distance_mm']:.1f} mm: {d['pair'][0]} with {d['pair'][1]}  "
            f"closing {d['closing_mm_s']:.0f} mm/s  S_p {d['separation_mm']:.1f} mm  override [{over}]  "
            f"cycle {d['cycle_us']:.0f} us  trips {d['trips']}")


def guard_off(cell) -> dict:
    """What droid-snoop guard says of a cell whose live guard is off (``[guard] run = false``)."""
    return {"subunit": GUARD, "cell": cell.name, "state": "off", "run": False}


def guard_off_text(d: dict, cell) -> str:
    return (f"guard: off in cell {d['cell']} ([guard] run = false in {cell.path}): no droid-guard runs; its bodies "
            "serve droid-move's refusal, droid-cell up's home check and droid-guard check (docs/guard.md)")


def _snoop_guard(cell, args) -> int:
    from droid.guard.gate import guard_runs
    from droid.guard.live import open_status
    from droid.guard.station import guard_status_dict

    if not guard_runs(cell):  # the Status database exists (droid-cell up makes it), nothing writes it
        d = guard_off(cell)
        print(json.dumps(d) if args.json else guard_off_text(d, cell), flush=True)
        return 0
    return _print_records(open_status(cell), args, guard_status_dict, guard_text)


if __name__ == "__main__":
    sys.exit(main())
