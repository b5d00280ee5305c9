"""Which databases a cell has, and their names (thesis §3.2–3.3, §4.1.3).

The layouts of each area come from the subunit's class (:mod:`droid.brain.cell.classes`);
for the classes shipped:

Brain (one per subunit):
  ``/droid.<cell>.<sub>.status``   ARM_STATUS (arm6r, Table 3.1) or SENSOR_STATUS (Table 3.3)
  ``/droid.<cell>.<sub>.command``  ARM_COMMAND (arm6r only, Table 3.2)
Subunit side (the motion controller's own, Tables 4.2–4.3; arm6r only):
  ``/droid.<cell>.<sub>.ctrl_status``   CTRL_STATUS
  ``/droid.<cell>.<sub>.ctrl_command``  CTRL_COMMAND
Subunit side for sensors: ``/droid.<cell>.<sub>.ctrl_status`` SENSOR_STATUS.
Joysticks: ``status`` and ``ctrl_status`` JOYSTICK_STATUS.
A cell that declares a collision guard (``[guard]``): ``/droid.<cell>.guard.status`` GUARD_STATUS
on the Brain's host (droid-guard writes it; docs/guard.md).
"""
from __future__ import annotations

from droid.brain.cell.cellfile import Cell, Subunit
from droid.brain.db.layouts import GUARD_STATUS_LAYOUT, JOG_MODE, JSPACE, Layout
from droid.brain.db.shmdb import Database, db_name


def brain_layouts(sub: Subunit) -> dict[str, Layout]:
    """The Brain's areas of a subunit -> layout (its class's ``brain`` table)."""
    return dict(sub.kind.brain)


def local_layouts(sub: Subunit) -> dict[str, Layout]:
    """The subunit side's areas -> layout (its class's ``local`` table)."""
    return dict(sub.kind.local)


def safe_start(db) -> None:
    """Give a fresh Command record (shm or in memory) the safe start values of §4.1.4: JOG mode and
    JOINT coordinates (§3.3), no command -- where its layout has them (an arm's)."""
    if "cmd_mode" in db.layout.dtype.names:
        db.update(cmd_mode=JOG_MODE, coord=JSPACE)


def create_databases(cell: Cell, hosts: set[str] | None = None, *, brain_only: bool = False) -> list[Database]:
    """Create (fresh) every database of the cell for ``hosts`` (default all); ``brain_only``:
    the Brain's Status/Command records only (a replay cell), no subunit's local records.

    Command records start "with safe values so that unwanted sudden motion is
    eliminated" (§4.1.4): JOG mode and JOINT coordinates (§3.3), no command."""
    made: list[Database] = []
    try:
        for sub in cell.subunits.values():
            areas = []
            if hosts is None or cell.brain_host in hosts:
                areas += list(brain_layouts(sub).items())
            if (hosts is None or sub.host in hosts) and not brain_only:
                areas += list(local_layouts(sub).items())
            for area, lay in areas:
                db = Database(db_name(cell.name, sub.name, area), lay, create=True)
                made.append(db)
                if area in ("command", "ctrl_command"):
                    safe_start(db)
        if "guard" in cell.raw and (hosts is None or cell.brain_host in hosts):
            # the collision guard's Status (droid-guard; docs/guard.md): a Brain record of its own
            made.append(Database(db_name(cell.name, "guard", "status"), GUARD_STATUS_LAYOUT, create=True))
    except Exception:
        for db in made:
            db.unlink()
        raise
    return made


def open_brain(cell: Cell, sub: Subunit, area: str, **kw) -> Database:
    return Database(db_name(cell.name, sub.name, area), brain_layouts(sub)[area], **kw)


def open_local(cell: Cell, sub: Subunit, area: str, **kw) -> Database:
    return Database(db_name(cell.name, sub.name, area), local_layouts(sub)[area], **kw)


def write_command(command: Database, **fields) -> int:
    """Write a new command into a Command record (Table 3.2): the fields, the next ``cmd_id``
    (never 0) and ``sent = 1``, under one lock.  Returns the ``cmd_id`` [tasks' one writer]."""
    with command.locked() as c:
        cmd_id = (int(c["cmd_id"]) + 1) & 0xFFFFFFFF or 1
        for k, v in fields.items():
            c[k] = v
        c["cmd_id"] = cmd_id
        c["sent"] = 1
        command.mark_written()
    return cmd_id
