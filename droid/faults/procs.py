"""Process faults: kill, pause (SIGSTOP) and resume (SIGCONT) a cell's programs; lock checks.

Programs are found the way ``droid-cell status`` finds them (the launcher's
records and the presence records in /dev/shm), by the name it shows
(``droid-servo arm1``) or by key.
"""
from __future__ import annotations

import os
import signal

from droid.brain.runtime import launcher
from droid.brain.cell.cellfile import Cell
from droid.brain.db.databases import brain_layouts, local_layouts
from droid.brain.db.layouts import PROC_STATUS_LAYOUT
from droid.brain.db.shmdb import Database, LockTimeout, NoDatabase, cell_objects, db_name
from droid.cli import BadInput, RuntimeFailure

ACTIONS = {"kill": signal.SIGKILL, "term": signal.SIGTERM, "pause": signal.SIGSTOP, "resume": signal.SIGCONT}


def programs(cell: Cell) -> list[dict]:
    """``droid-cell status`` rows (name, key, host, pid, alive, live, last_tick, ...)."""
    return launcher.status(cell)


def find(cell: Cell, name: str) -> dict:
    rows = programs(cell)
    for r in rows:
        if name in (r["name"], r["key"]):
            return r
    raise BadInput(f"no program {name!r} in cell {cell.name!r} (programs: {', '.join(r['name'] for r in rows)})")


def signal_program(cell: Cell, name: str, action: str) -> int:
    """Send ``action`` (kill, term, pause, resume) to one program; returns its pid."""
    if action not in ACTIONS:
        raise BadInput(f"unknown action {action!r} (known: {', '.join(ACTIONS)})")
    row = find(cell, name)
    pid = int(row["pid"])
    if pid <= 0 or not row["alive"]:
        raise RuntimeFailure(f"{row['name']} is not running")
    try:
        os.kill(pid, ACTIONS[action])
    except ProcessLookupError:
        raise RuntimeFailure(f"{row['name']} (pid {pid}) is gone") from None
    return pid


def cell_databases(cell: Cell) -> list[tuple[str, object]]:
    """(shm name, layout) of every database of the cell that exists now, presence records included."""
    out = []
    for sub in cell.subunits.values():
        for area, lay in (*brain_layouts(sub).items(), *local_layouts(sub).items()):
            out.append((db_name(cell.name, sub.name, area), lay))
    prefix = f"droid.{cell.name}.proc."
    for entry in cell_objects(cell.name):
        if entry.startswith(prefix) and not entry.endswith(".rec"):
            out.append(("/" + entry, PROC_STATUS_LAYOUT))
    present = {"/" + e for e in cell_objects(cell.name)}
    return [(n, lay) for n, lay in out if n in present]


def wedged_databases(cell: Cell, timeout_s: float | None = None) -> list[str]:
    """Databases of the cell whose semaphore cannot be taken within the timeout
    (recovering from a dead holder as every program would)."""
    wedged = []
    for name, lay in cell_databases(cell):
        kw = {} if timeout_s is None else {"timeout_s": timeout_s}
        try:
            db = Database(name, lay, **kw)
        except (NoDatabase, BadInput):
            continue  # removed meanwhile (a presence record of a program that exited)
        try:
            with db.locked():
                pass
        except LockTimeout:
            wedged.append(name)
        finally:
            db.close()
    return wedged
