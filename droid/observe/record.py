"""droid-record: the cell's black box (thesis §3.4, §7.3; docs/design.md §10 "Recordings are the cell's black box").

``droid-record --out FILE.mcap [--cell FILE] [--seconds S] [SUBUNIT ...]``
records, by heartbeat tick, every Brain Status and Command database of the
cell (or of the SUBUNITs named), the sensor readings with their stamps (a
sensor's Status, Table 3.3: x, y, R, ``tick``, ``updated_ns``), program health
(the ``droid-cell status --json`` fields, 5 times a second), faults and
events (foxglove ``Log``), the frames (foxglove ``FrameTransforms``: arm
bases, wrist centres, tool, sensor, workpiece; every tick) and the scene
(foxglove ``SceneUpdate``: workpiece and seam map; twice a second) into one
MCAP file (layout: :mod:`droid.observe.mcapfile`).  It reads the databases
only, like a task; it never writes a Command.

The core, :class:`CellRecorder`, takes plain records per tick, so the same
writer serves ``droid-seamtrack --record FILE`` (:class:`LiveRecorder`, one
call per tick from the task's loop) and lockstep trials
(``droid-experiment run --record``, :mod:`droid.observe.lockstep`).

``droid-record --format rosbag2 --out DIR [--force]`` writes a ROS 2 bag instead,
directly (no MCAP recording first): the same core feeds a
:class:`~droid.observe.bag.BagSink`, which converts each tick's Status records
as the next tick starts (:mod:`droid.observe.bag`); the counts per topic go to
stdout at the end.

Ticks the recorder could not sample (a loaded host) are counted as ``missed``
in ``/tick`` and logged; it runs SCHED_FIFO below every program of the cell
when the cell file asks for ``sched_fifo``.

Exit: 0 after ``--seconds`` or on SIGINT/SIGTERM (the file is finished either
way); 1 cell not up or heartbeat lost; 2 bad arguments.
"""
from __future__ import annotations

import os
import sys
import time

import zmq

from droid.brain.runtime.heartbeat import TickSubscriber
from droid.brain.runtime.program import Stop, open_cell, parser
from droid.brain.runtime.rt import try_sched_fifo
from droid.cli import BadInput, RuntimeFailure, duration_s, run
from droid.observe import schemas
from droid.observe.events import EventWatcher
from droid.observe.mcapfile import TOPIC_HEALTH, TOPIC_SCENE, TOPIC_TF, RecordingWriter, cell_meta
from droid.observe.sampler import CellSampler, health
from droid.observe.scene import SceneBuilder, is_arm, scene_meta

PROG = "droid-record"
HEALTH_TICKS = 12  # program health every 12 ticks (5 Hz at 60 Hz)
SCENE_TICKS = 30  # SceneUpdate every 30 ticks (2 Hz): it carries the whole seam map
HEARTBEAT_LOST_S = 2.0
#: SCHED_FIFO priority when the cell asks for it (cell file ``sched_fifo``): below every program of
#: the cell (remotes and heartbeat 50, the tracking loop 49, the GMF1 encoder 45), so the recorder
#: never delays the cell, but above the normal scheduler's load, so a busy host drops fewer ticks.


class CellRecorder:
    """The recording core: one :meth:`sample` per heartbeat tick.  No clock, no shared memory."""

    def __init__(self, writer: RecordingWriter, *, health_ticks: int = HEALTH_TICKS,
                 scene_ticks: int = SCENE_TICKS) -> None:
        self.w = writer
        meta = writer.meta
        subs = meta.get("subunits", [])
        self.scene = SceneBuilder(subs, meta.get("scene", {}))
        self.events = EventWatcher({s["name"] for s in subs if is_arm(s)})
        self.health_ticks, self.scene_ticks = health_ticks, scene_ticks
        self.samples = 0

    def wants_health(self) -> bool:
        return self.samples % self.health_ticks == 0

    def sample(self, tick: int, t_ns: int, records, *, missed: int = 0, health_row: dict | None = None) -> None:
        """Write one tick: ``records`` = ``[(subunit, area, layout, record or dict)]``; ``t_ns`` [ns] is
        the message time; ``health_row``: :func:`droid.observe.sampler.health` output, when sampled."""
        w = self.w
        w.tick(tick, t_ns, missed)
        statuses = {}
        for sub, area, lay, rec in records:
            d = w.record(sub, area, lay, rec, tick, t_ns)
            if area == "status":
                statuses[sub] = d
        for level, name, msg in self.events.step(statuses, missed):
            w.log(tick, t_ns, level, msg, name)
        if health_row is not None:
            w.write(TOPIC_HEALTH, schemas.HEALTH, dict(health_row), tick, t_ns)
            for level, name, msg in self.events.health(health_row.get("programs", [])):
                w.log(tick, t_ns, level, msg, name)
        geo = self.scene.step(statuses)
        w.write(TOPIC_TF, schemas.FRAME_TRANSFORMS, self.scene.frame_transforms(geo["frames"], t_ns), tick, t_ns)
        if self.samples % self.scene_ticks == 0:
            w.write(TOPIC_SCENE, schemas.SCENE_UPDATE, self.scene.scene_update(geo, t_ns), tick, t_ns)
        self.samples += 1

    def close(self) -> None:
        self.w.close()


class LiveRecorder:
    """A running cell's databases into a recording, one :meth:`on_tick` per heartbeat tick
    (used by droid-record and by ``droid-seamtrack --record``)."""

    def __init__(self, cell, path: str, subunits: list[str] | None = None, *, layout_path=None,
                 fmt: str = "mcap", force: bool = False) -> None:
        if fmt == "mcap":
            check_out_path(path)
        self.cell = cell
        self.sampler = CellSampler(cell, subunits)
        self.sampler.connect()
        try:
            meta = cell_meta(cell, "live", scene_meta(cell, layout_path))
            chosen = {s.name for s in self.sampler.subs}
            meta["subunits"] = [s for s in meta["subunits"] if s["name"] in chosen]
            if fmt == "rosbag2":
                from droid.observe.bag import BagSink

                self.core = CellRecorder(BagSink(path, meta, force=force))
            else:
                self.core = CellRecorder(RecordingWriter(path, meta))
        except BaseException:
            self.sampler.close()
            raise
        self.last_tick: int | None = None

    def on_tick(self, tick: int, missed: int = 0) -> None:
        if self.last_tick is not None and tick <= self.last_tick:
            return
        gap = 0 if self.last_tick is None else max(0, tick - self.last_tick - 1)
        self.last_tick = tick
        h = health(self.cell) if self.core.wants_health() else None
        self.core.sample(tick, time.time_ns(), self.sampler.read(), missed=max(gap, missed), health_row=h)

    def close(self) -> None:
        try:
            self.core.close()
        finally:
            self.sampler.close()


def check_out_path(path: str) -> None:
    """BadInput unless ``path`` can be written (its directory exists; not a directory)."""
    d = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(d):
        raise BadInput(f"directory of {path} does not exist")
    if os.path.isdir(path):
        raise BadInput(f"{path} is a directory")


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Record a cell's databases, health, events, frames and scene into an MCAP file.")
    ap.add_argument("--out", required=True, metavar="FILE.mcap|DIR",
                    help="the recording to write (with --format rosbag2: the bag directory to create)")
    ap.add_argument("--format", choices=("mcap", "rosbag2"), default="mcap",
                    help="mcap (default): DROID's recording; rosbag2: a ROS 2 bag (storage mcap) written directly")
    ap.add_argument("--force", action="store_true", help="with --format rosbag2: replace an existing bag in DIR")
    ap.add_argument("--seconds", type=duration_s(), default=None, metavar="S",
                    help="stop after S seconds (default: until SIGINT/SIGTERM)")
    ap.add_argument("subunits", nargs="*", metavar="SUBUNIT", help="record only these subunits (default: all)")
    args = ap.parse_args(argv)
    if args.force and args.format != "rosbag2":
        ap.error("--force goes with --format rosbag2")
    cell = open_cell(args)
    for name in args.subunits:
        cell.subunit(name)
    Stop.install()
    rec = LiveRecorder(cell, args.out, args.subunits or None, fmt=args.format, force=args.force)
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    ctx = zmq.Context.instance()
    ticks = TickSubscriber(ctx, cell.heartbeat)
    t_end = None if args.seconds is None else time.monotonic() + args.seconds
    last = time.monotonic()
    why = "interrupted"
    try:
        while not Stop.requested:
            now = time.monotonic()
            if t_end is not None and now >= t_end:
                why = f"{args.seconds:g} s recorded"
                break
            t = ticks.wait(0.1)
            if t is None:
                if time.monotonic() - last > HEARTBEAT_LOST_S:
                    raise RuntimeFailure(f"heartbeat lost (no tick for {HEARTBEAT_LOST_S:g} s): is the cell up?")
                continue
            last = time.monotonic()
            rec.on_tick(t.tick)
    finally:
        ticks.close()
        rec.close()
    w = rec.core.w
    if args.format == "rosbag2":
        from droid.observe.bag import summary_lines

        for line in summary_lines(w.bag.counts, w.bag.types):
            print(line)
        print(f"{PROG}: {why}: {rec.core.samples} ticks, {w.messages} messages in the ROS 2 bag {args.out}",
              file=sys.stderr)
        return 0
    print(f"{PROG}: {why}: {rec.core.samples} ticks, {w.messages} messages, "
          f"{os.path.getsize(args.out) / 1e6:.2f} MB in {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
