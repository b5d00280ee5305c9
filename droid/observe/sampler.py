"""One snapshot of a running cell's Brain databases (read-only, like a task, thesis §3.4).

:class:`CellSampler` opens every Brain database of the chosen subunits --
whatever areas :func:`droid.brain.db.databases.brain_layouts` gives each, so a
new subunit class or area is recorded without a change here -- and reads
them all on :meth:`read` -- and the collision guard's Status where the cell declares one.  :func:`health` gives the ``droid-cell status --json``
rows plus the heartbeat's worst lateness [ns].  Nothing here writes.
"""
from __future__ import annotations

from droid.brain.db.databases import brain_layouts, open_brain
from droid.brain.db.layouts import GUARD_STATUS_LAYOUT, PROC_STATUS_LAYOUT, Layout
from droid.brain.runtime.program import presence_key
from droid.brain.db.shmdb import Database, NoDatabase, db_name
from droid.cli import BadInput, DroidError


#: the collision guard's record in a recording: subunit "guard", area "status" (topic /guard/status)
GUARD = "guard"


class CellSampler:
    """Reads the Brain's Status/Command records of ``subunits`` (default: all of the cell)."""

    def __init__(self, cell, subunits: list[str] | None = None) -> None:
        self.cell = cell
        names = subunits or list(cell.subunits)
        self.whole = not subunits  # the whole cell: the guard's Status too
        self.subs = [cell.subunit(n) for n in names]  # BadInput on an unknown name
        self.dbs: list[tuple[str, str, Layout, Database]] = []

    def connect(self) -> "CellSampler":
        try:
            for sub in self.subs:
                for area, lay in brain_layouts(sub).items():
                    self.dbs.append((sub.name, area, lay, open_brain(self.cell, sub, area)))
            if self.whole and "guard" in self.cell.raw and GUARD not in self.cell.subunits:
                # the collision guard's own Status (droid-guard; docs/guard.md), as "guard" / "status"
                try:
                    db = Database(db_name(self.cell.name, GUARD, "status"), GUARD_STATUS_LAYOUT)
                except NoDatabase:
                    pass  # a cell brought up without it (droid-cell init, a replay cell)
                else:
                    self.dbs.append((GUARD, "status", GUARD_STATUS_LAYOUT, db))
        except BaseException:
            self.close()
            raise
        return self

    def read(self) -> list[tuple[str, str, Layout, object]]:
        """``[(subunit, area, layout, record)]``: a consistent copy of each record."""
        return [(s, a, lay, db.read()) for s, a, lay, db in self.dbs]

    def close(self) -> None:
        for *_, db in self.dbs:
            db.close()
        self.dbs = []

    def __enter__(self) -> "CellSampler":
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()


def health(cell) -> dict:
    """Program health: ``{"programs": droid-cell status --json rows, "heartbeat": {...}}``
    (empty rows when the cell has no programs, e.g. a replay cell)."""
    from droid.brain.runtime.launcher import status

    try:
        rows = status(cell)
    except DroidError:
        rows = []
    hb = {}
    try:
        db = Database(db_name(cell.name, "proc", presence_key("droid-heartbeat")), PROC_STATUS_LAYOUT, timeout_s=0.2)
    except (NoDatabase, BadInput):
        db = None
    if db is not None:
        try:
            rec = db.read()
            hb = {"lateness_max_ns": int(rec["lateness_max_ns"]), "overruns": int(rec["overruns"]),
                  "last_tick": int(rec["last_tick"])}
        except DroidError:
            pass
        finally:
            db.close()
    return {"programs": rows, "heartbeat": hb}
