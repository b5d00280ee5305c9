"""droid-replay: play a recording back into a replay cell's Brain databases, or export it.

``droid-replay FILE.mcap [--cell FILE] [--rate X] [--from TICK] [--to TICK]``
    writes every recorded Status and Command record, tick by tick, at the
    recorded pace (``--rate 2`` twice as fast) into the Brain databases of a
    cell brought up with ``droid-cell up --replay FILE`` -- databases only: no
    world, no subunit programs, no remotes -- so ``droid-snoop``, ``droid-web``
    and read-only tasks read the recorded cell as if it ran.  It refuses a
    live cell (its programs own those records) and a cell whose database
    layouts differ from the recording's, naming both versions.
``droid-replay FILE --export csv --subunit arm1 [--area status] [--from TICK] [--to TICK] [--out F]``
    one CSV row per recorded tick of one database: ``tick`` (the heartbeat tick
    of the sample) then every field (arrays flattened as ``name_i`` /
    ``name_i_j``; the record's own ``tick`` as ``record_tick``; the header's
    bookkeeping left out).
``droid-replay FILE --export rosbag2 DIR [--force] [--from TICK] [--to TICK]``
    a ROS 2 bag (storage mcap) of the recording: joint states, tool poses, /tf, the sensors'
    readings, /rosout (:mod:`droid.observe.bag`); one line per topic on stdout: topic, type,
    message count.  An existing DIR is refused (exit 2) unless ``--force`` (a bag or an empty
    directory only).
``droid-replay FILE --recover OUT.mcap``
    rewrites the whole chunks of a recording that stopped uncleanly.

A truncated, foreign or future-version file: one line on stderr, exit 2.
Exit 0 at the end of the recording or on SIGINT; 1 the cell is not a replay cell / not up.
"""
from __future__ import annotations

import csv
import json
import os
import sys
import time

from droid.brain.db.databases import brain_layouts, open_brain
from droid.brain.db.layouts import HEADER_FIELDS
from droid.brain.runtime.program import Presence, Stop, open_cell, parser
from droid.cli import BadInput, RuntimeFailure, bounded_float, bounded_int, run
from droid.observe import schemas
from droid.observe.mcapfile import Recording, db_topic, read_recording, recover
from droid.observe.sampler import GUARD
from droid.brain.db.layouts import GUARD_STATUS_LAYOUT
from droid.brain.db.shmdb import Database, db_name

PROG = "droid-replay"
REPLAY_KEY = "replay"  # cell.json of a replay cell: {"replay": FILE, "programs": []}
SKIP_CSV = {name for name, _, _ in HEADER_FIELDS} - {"seq"}


def _is_guard(cell, sub_name: str, area: str) -> bool:
    """The collision guard's Status (recorded as "guard" / "status" where the cell declares one)."""
    return sub_name == GUARD and area == "status" and GUARD not in cell.subunits and "guard" in cell.raw


def check_layouts(cell, rec: Recording) -> None:
    """BadInput unless every recorded database exists in ``cell`` with the same layout and version."""
    for (sub_name, area), (lay_name, ver) in sorted(rec.layouts().items()):
        if _is_guard(cell, sub_name, area):
            if (lay_name, ver) != (GUARD_STATUS_LAYOUT.name, GUARD_STATUS_LAYOUT.version):
                raise BadInput(f"{rec.path}: guard status: the recording has {lay_name} version {ver}, cell "
                               f"{cell.name} has {GUARD_STATUS_LAYOUT.name} version {GUARD_STATUS_LAYOUT.version}")
            continue
        if sub_name not in cell.subunits:
            raise BadInput(f"{rec.path}: recorded subunit {sub_name} is not in cell {cell.name} "
                           f"(cell subunits: {', '.join(cell.subunits)})")
        have = brain_layouts(cell.subunits[sub_name]).get(area)
        if have is None:
            raise BadInput(f"{rec.path}: {sub_name} {area}: the recording has {lay_name} version {ver}, "
                           f"cell {cell.name} has no such database")
        if (have.name, have.version) != (lay_name, ver):
            raise BadInput(f"{rec.path}: {sub_name} {area}: the recording has {lay_name} version {ver}, "
                           f"cell {cell.name} has {have.name} version {have.version}")


def replay_state(cell) -> dict | None:
    """The replay cell's state file (None when the cell was not brought up with --replay)."""
    try:
        with open(cell.run_dir / "cell.json") as f:
            st = json.load(f)
    except (OSError, ValueError):
        return None
    return st if REPLAY_KEY in st else None


def tick_range(rec: Recording, t_from: int | None, t_to: int | None) -> range:
    import bisect

    lo = 0 if t_from is None else bisect.bisect_left(rec.ticks, t_from)
    hi = len(rec.ticks) if t_to is None else bisect.bisect_right(rec.ticks, t_to)
    return range(lo, max(lo, hi))


def flatten(d: dict) -> dict:
    """A record dict as flat CSV columns (header bookkeeping dropped, arrays as name_i / name_i_j)."""
    out = {}
    for k, v in d.items():
        if k in SKIP_CSV or k.startswith("_"):
            continue
        if isinstance(v, list):
            for i, x in enumerate(v):
                if isinstance(x, list):
                    for j, y in enumerate(x):
                        out[f"{k}_{i}_{j}"] = y
                else:
                    out[f"{k}_{i}"] = x
        else:
            out[k] = v
    return out


def export_csv(rec: Recording, subunit: str, area: str, ticks: range, out) -> int:
    topic = db_topic(subunit, area)
    if topic not in rec.channels:
        have = sorted({t.split("/")[1] for t in rec.channels if t.count("/") == 2})
        raise BadInput(f"{rec.path}: no {area} of {subunit!r} recorded (subunits: {', '.join(have)})")
    w = None
    n = 0
    for i in ticks:
        msgs = rec.frames[i].get(topic)
        if not msgs:
            continue
        fields = flatten(msgs[-1])
        if "tick" in fields:  # the record's own tick (when its writer last refreshed it)
            fields["record_tick"] = fields.pop("tick")
        row = {"tick": rec.ticks[i], **fields}
        if w is None:
            w = csv.DictWriter(out, fieldnames=list(row), lineterminator="\n")
            w.writeheader()
        w.writerow(row)
        n += 1
    return n


def play(cell, rec: Recording, ticks: range, rate: float, on_tick=None) -> int:
    """Write the recorded records of ``ticks`` into the cell's Brain databases at ``rate`` x the recorded
    pace; ``on_tick(tick, n)`` after each tick written."""
    dbs = {}
    try:
        for (sub_name, area) in rec.layouts():
            if _is_guard(cell, sub_name, area):
                dbs[db_topic(sub_name, area)] = (Database(db_name(cell.name, GUARD, "status"), GUARD_STATUS_LAYOUT),
                                                 GUARD_STATUS_LAYOUT)
                continue
            dbs[db_topic(sub_name, area)] = (open_brain(cell, cell.subunits[sub_name], area),
                                             brain_layouts(cell.subunits[sub_name])[area])
        if not len(ticks):
            return 0
        t0 = rec.t_ns[ticks[0]]
        start = time.monotonic()
        n = 0
        for i in ticks:
            if Stop.requested:
                break
            due = start + (rec.t_ns[i] - t0) / 1e9 / rate
            while not Stop.requested:
                left = due - time.monotonic()
                if left <= 0:
                    break
                time.sleep(min(left, 0.1))
            for topic, msgs in rec.frames[i].items():
                target = dbs.get(topic)
                if target is None:
                    continue
                db, lay = target
                r = db.read()
                schemas.dict_to_record(msgs[-1], lay, r)
                db.write(r)
            n += 1
            if on_tick is not None:
                on_tick(rec.ticks[i], n)
        return n
    finally:
        for db, _ in dbs.values():
            db.close()


#: A heartbeat tick number (the recordings' uint64 ticks; 2**62 ticks is 2.4 billion years at 60 Hz).
tick = bounded_int(0, 2**62, "ticks")


def export_bag(args, ap) -> int:
    """``--export rosbag2``: the bag, and one line per topic on stdout (topic, type, messages)."""
    from droid.observe.bag import export_rosbag2, summary_lines

    if args.bag_dir is not None and args.out is not None and args.bag_dir != args.out:
        ap.error("give the bag directory once (DIR or --out DIR)")
    out = args.bag_dir or args.out
    if not out or out == "-":
        ap.error("--export rosbag2 needs a bag directory: --export rosbag2 DIR")
    if args.subunit is not None:
        ap.error("--subunit goes with --export csv (a bag holds every subunit)")
    w, conv = export_rosbag2(args.file, out, force=args.force, t_from=args.t_from, t_to=args.t_to)
    for line in summary_lines(w.counts, w.types):
        print(line)
    for name, why in sorted(conv.skipped().items()):
        print(f"{PROG}: {name} left out of the bag: {why}", file=sys.stderr)
    print(f"{PROG}: {sum(w.counts.values())} messages on {len(w.counts)} topics in {out} "
          f"(ROS 2 bag, storage mcap)", file=sys.stderr)
    return 0


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Play a DROID recording back into a replay cell, export one database as CSV, or recover it.")
    ap.add_argument("file", metavar="FILE.mcap", help="a recording made by droid-record")
    ap.add_argument("--rate", type=bounded_float(0.01, 1000.0, "x"), default=1.0, metavar="X",
                    help="playback speed, x the recorded pace (default 1)")
    ap.add_argument("--from", dest="t_from", type=tick, default=None, metavar="TICK",
                    help="first heartbeat tick")
    ap.add_argument("--to", dest="t_to", type=tick, default=None, metavar="TICK",
                    help="last heartbeat tick")
    ap.add_argument("--export", choices=("csv", "rosbag2"), default=None,
                    help="csv: write one database as CSV; rosbag2: write a ROS 2 bag into DIR (instead of playing)")
    ap.add_argument("bag_dir", nargs="?", default=None, metavar="DIR",
                    help="with --export rosbag2: the bag directory to create (or --out DIR)")
    ap.add_argument("--force", action="store_true", help="with --export rosbag2: replace an existing bag in DIR")
    ap.add_argument("--subunit", default=None, metavar="NAME", help="with --export: the subunit, e.g. arm1")
    ap.add_argument("--area", default="status", metavar="AREA", help="with --export: status (default) or command")
    ap.add_argument("--out", default=None, metavar="FILE",
                    help="with --export csv: the CSV file (default stdout); with --export rosbag2: the bag directory")
    ap.add_argument("--recover", default=None, metavar="OUT.mcap",
                    help="rewrite the whole chunks of a truncated recording into OUT.mcap")
    args = ap.parse_intermixed_args(argv)
    if args.bag_dir is not None and args.export != "rosbag2":
        ap.error(f"unexpected argument {args.bag_dir!r} (a directory goes with --export rosbag2)")
    if args.force and args.export != "rosbag2":
        ap.error("--force goes with --export rosbag2")
    if args.t_from is not None and args.t_to is not None and args.t_to < args.t_from:
        ap.error(f"--to {args.t_to} is before --from {args.t_from}")
    if args.recover:
        if os.path.abspath(args.recover) == os.path.abspath(args.file):
            raise BadInput("--recover OUT.mcap must be another file")
        rec = recover(args.file, args.recover)
        print(f"{PROG}: {len(rec.ticks)} ticks recovered into {args.recover}", file=sys.stderr)
        return 0
    if args.export == "rosbag2":
        return export_bag(args, ap)
    if args.export:
        if not args.subunit:
            ap.error("--export needs --subunit NAME")
        rec = read_recording(args.file)
        ticks = tick_range(rec, args.t_from, args.t_to)
        if args.out in (None, "-"):
            export_csv(rec, args.subunit, args.area, ticks, sys.stdout)
        else:
            with open(args.out, "w", newline="") as f:
                export_csv(rec, args.subunit, args.area, ticks, f)
        return 0
    rec = read_recording(args.file)
    cell = open_cell(args)
    check_layouts(cell, rec)
    st = replay_state(cell)
    if st is None:
        raise RuntimeFailure(f"cell {cell.name} is not a replay cell: bring it up with "
                             f"'droid-cell up --replay {args.file}' (a live cell's programs own its records)")
    Stop.install()
    pres = Presence(cell.name, "replay", f"droid-replay {os.path.basename(args.file)}"[:31])
    pres.ready()
    try:
        n = play(cell, rec, tick_range(rec, args.t_from, args.t_to), args.rate,
                 on_tick=lambda tick, k: pres.beat(tick, k))
    finally:
        pres.close()
    print(f"{PROG}: {n} ticks replayed into cell {cell.name}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
