"""Cell files (docs/design.md §5): one TOML file describes a cell.

A cell is one Brain plus subunits.  The file names the subunits, their class
(``arm6r``, ``line_laser``), robot model, base pose in the global frame, the
programs each subunit runs, endpoints, rates and driver URLs.  ``{run}`` and
``{cell}`` in any string expand to the cell's run directory and name, ``{loopback}`` to the
cell's own loopback address (:func:`loopback_address`).

``--cell FILE`` everywhere; the default comes from ``$DROID_CELL``, else the
built-in simulated cell ``cells/sim.toml`` shipped inside the package.

Validation is strict: an unknown key, a wrong type or a missing section is a
:class:`~droid.cli.BadInput` with the file and the key in the message.
"""
from __future__ import annotations

import hashlib

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from droid.cli import BadInput, TableReader, read_toml
from droid.numbers import NumberError, check_numbers, finite_numbers
from droid.brain.cell.classes import SubunitClass
from droid.brain.cell import registry as _registry
from droid.brain.plumbing.curve import CurveConfig, parse_curve_table
from droid.brain.plumbing.wire import LIVENESS_TICKS
from droid.brain.db.shmdb import check_name_part

#: The heartbeat rates a cell accepts [Hz] ([cell] heartbeat_hz, droid-heartbeat --rate): at
#: least 1 Hz (the stale rules count ticks), at most 1000 Hz (a 1 ms period).
HEARTBEAT_HZ_RANGE = (1.0, 1000.0)



def __getattr__(name: str):
    if name == "SUBUNIT_CLASSES":  # the class names of the device registry (droid.brain.cell.registry)
        return tuple(_registry.classes())
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


DEFAULT_RUN_ROOT = "/tmp/droid"
ENV_CELL = "DROID_CELL"
ENV_RUN_ROOT = "DROID_RUN_ROOT"


def builtin_cell_path() -> Path:
    """The default simulated cell shipped with the package."""
    return BUNDLED_CELLS / "sim.toml"


#: the folder of the cells (and their layouts) shipped with the package
BUNDLED_CELLS = Path(__file__).resolve().parents[2] / "cells"  # droid/cells/


def find_file(spec: str, folder: Path, suffix: str = "") -> Path | None:
    """A file named in a cell or plan file: ``spec`` relative to ``folder``, else, for a bare
    name, the bundled one of that name (``spec`` or ``spec`` + ``suffix``), as robot files are
    found by name; None when there is neither."""
    path = Path(spec)
    cand = path if path.is_absolute() else folder / path
    if cand.is_file():
        return cand.resolve()
    if len(path.parts) == 1:
        for name in (spec, spec + suffix) if suffix else (spec,):
            if (BUNDLED_CELLS / name).is_file():
                return (BUNDLED_CELLS / name).resolve()
    return None


#: a TOML table header line (``[a.b]`` or ``[[a]]`` at the line's start), not an array's continuation
_TABLE_HEADER = re.compile(r"^\[\[?[A-Za-z0-9_.\"' -]+\]\]?\s*(#.*)?$")


def without_table(text: str, header: str) -> str:
    """A cell file's text without one table (``header``, e.g. ``[world.devices.touch]``: its
    header line up to the next table's header), for programs that derive a cell from the
    built-in one (droid-experiment --realtime, the tests' fixed arms).  ValueError if the
    text has no such table."""
    lines = text.splitlines(keepends=True)
    try:
        start = next(i for i, ln in enumerate(lines) if ln.strip() == header)
    except StopIteration:
        raise ValueError(f"no table {header} in the cell text") from None
    end = next((i for i in range(start + 1, len(lines)) if _TABLE_HEADER.match(lines[i])), len(lines))
    while end > start + 1 and lines[end - 1].lstrip().startswith("#"):  # the next table's own comments
        end -= 1
    return "".join(lines[:start] + lines[end:])


def default_cell_path() -> Path:
    env = os.environ.get(ENV_CELL)
    return Path(env) if env else builtin_cell_path()


@dataclass
class Subunit:
    """One subunit of the cell (thesis §3.2)."""

    name: str
    cls: str  # a class of the device registry (droid.brain.cell.registry): arm6r, line_laser, joystick, ...
    host: str
    agent: str  # ZeroMQ endpoint the agent binds
    relay: str  # ZeroMQ endpoint where the agent relays ticks to its local programs
    programs: list[str]
    robot: str | None = None  # robot model name (arm6r)
    base: list[float] = field(default_factory=lambda: [0.0] * 6)  # x y z mm, ZYZ deg
    description: str = ""
    options: dict[str, Any] = field(default_factory=dict)  # class-specific tables

    @property
    def kind(self) -> SubunitClass:
        """The subunit's class as data (layouts, fields, drivers)."""
        return _registry.classes()[self.cls]

    @property
    def is_arm(self) -> bool:
        """A commandable arm with a robot model (its class is kinematic)."""
        return _registry.classes()[self.cls].kinematic

    def check_class(self, cls: str, what: str) -> None:
        """BadInput ``NAME is a CLS subunit, not WHAT`` unless the subunit is of class ``cls``."""
        if self.cls != cls:
            raise BadInput(f"{self.name} is a {self.cls} subunit, not {what}")

    def device_url(self, what: str, example: str) -> str:
        """The subunit's ``device`` URL (BadInput ``[subunits.NAME] WHAT needs 'device' (e.g. EXAMPLE)``
        when it has none)."""
        url = self.options.get("device")
        if not isinstance(url, str) or not url:
            raise BadInput(f"[subunits.{self.name}] {what} needs 'device' (e.g. \"{example}\")")
        return url


REMOTES_EACH, REMOTES_ONE = "each", "one"


@dataclass
class Cell:
    """A parsed, validated cell file."""

    path: Path
    name: str
    heartbeat_hz: float
    stale_ticks: int
    sched_fifo: bool
    run_dir: Path
    brain_host: str
    heartbeat: str
    names: str
    world: dict[str, Any]
    subunits: dict[str, Subunit]
    curve: CurveConfig | None  # [curve]: CURVE keys for tcp:// links (None: no keys)
    raw: dict[str, Any]
    # [interpose] public endpoint -> the endpoint its owner binds instead, so that a
    # fault proxy (droid-fault) can serve the public one (docs/safety.md)
    interpose: dict[str, str] = field(default_factory=dict)
    # [cell] layout: the cell's seam-tracking layout (droid.brain.cell.cell_layout), a path relative
    # to the cell file; None: the bundled seamtrack_layout.toml
    layout: Path | None = None
    # [brain] remotes: "each" -- one droid-remote per subunit (thesis §3.2); "one" -- one
    # droid-remote process serves every agent-linked subunit (issue 28 item 4: a subunit's
    # remote costs its wake-ups, not its work; serial-linked sensors keep their own)
    remotes: str = REMOTES_EACH
    # [cell] share: programs of which one process per host serves every subunit of that host
    # that names it (e.g. droid-agent, droid-joystick; issue 28 item 4) -- each declared
    # ``several`` in its device package (droid.brain.cell.registry.Program)
    share: tuple[str, ...] = ()
    # [ros2] domain_id: droid-ros2's ROS 2 domain id when --domain is not given (None: $ROS_DOMAIN_ID, else 0)
    ros2_domain: int | None = None

    def bind_endpoint(self, endpoint: str) -> str:
        """Where the owner of ``endpoint`` binds: itself, or its [interpose] inner endpoint."""
        return self.interpose.get(endpoint, endpoint)

    @property
    def period_ns(self) -> int:
        return int(round(1e9 / self.heartbeat_hz))

    def subunit(self, name: str) -> Subunit:
        try:
            return self.subunits[name]
        except KeyError:
            known = ", ".join(sorted(self.subunits)) or "none"
            raise BadInput(f"unknown subunit {name!r} in cell {self.name!r} (known: {known})") from None

    def hosts(self) -> list[str]:
        hs = {self.brain_host, str(self.world.get("host", self.brain_host))}
        hs.update(s.host for s in self.subunits.values())
        return sorted(hs)


#: the workpiece's shape for viewers, written by droid-sim into the cell's run directory
#: (droid.sim.mvs.devices.publish_workpiece_mesh), read by droid-web (droid.observe.scene)
WORKPIECE_MESH_FILE = "workpiece_mesh.json"


def loopback_address(cell: str) -> str:
    """The cell's own loopback address, ``127.a.b.c`` from a hash of its name (``{loopback}``).

    A device on Ethernet listens on its vendor's fixed port (a Net F/T on UDP 49152, an ABB
    controller's EGM on its configured port); its twin in droid-sim does too.  Every address of
    127.0.0.0/8 is this host's loopback, so each cell binds its twins on an address of its own
    and two cells (two test runs, a user's cell beside the default one) never contend for a
    port.  127.0.0.1 itself is never chosen."""
    h = hashlib.sha1(cell.encode()).digest()
    a, b, c = (1 + x % 254 for x in h[:3])
    return f"127.{a}.{b}.{c}"


def _expand(value: Any, run: str, cell: str) -> Any:
    if isinstance(value, str):
        return value.replace("{run}", run).replace("{cell}", cell).replace("{loopback}", loopback_address(cell))
    if isinstance(value, list):
        return [_expand(v, run, cell) for v in value]
    if isinstance(value, dict):
        return {k: _expand(v, run, cell) for k, v in value.items()}
    return value


class _Reader(TableReader):
    """Typed, key-checked access to one TOML table of a cell file."""

    def __init__(self, path: Path, where: str, table: Any) -> None:
        if not isinstance(table, dict):
            raise BadInput(f"{path}: [{where}] must be a table")
        super().__init__(f"{path}: [{where}]", table)

    def done(self, allow_extra: bool = False) -> dict[str, Any]:
        extra = {k: v for k, v in self.table.items() if k not in self.used}
        if extra and not allow_extra:
            raise BadInput(f"{self.where} unknown key(s): {', '.join(self.unused())}")
        return extra


def _positive(v) -> str | None:
    return None if (math.isfinite(v) and v > 0) else "must be a finite number > 0"


def _endpoint(v: str) -> str | None:
    return None if v.startswith(("ipc://", "tcp://", "inproc://")) else "must be an ipc://, tcp:// or inproc:// endpoint"


def _interposed(public: str, inner: str) -> str | None:
    """An [interpose] pair: ZeroMQ endpoints, or two ``udp://`` addresses (an EGM link)."""
    udp = [v.startswith("udp://") for v in (public, inner)]
    if any(udp) and not all(udp):
        return "a udp:// address is interposed by a udp:// address only"
    return None if all(udp) else _endpoint(public) or _endpoint(inner)


def _interpose_table(table: dict, p: Path, run: str, cell: str) -> dict[str, str]:
    """[interpose]: public endpoint -> inner endpoint, checked and expanded."""
    out = {}
    for public, inner in table.items():
        if not isinstance(inner, str):
            raise BadInput(f"{p}: [interpose] {public!r} must map to a string")
        msg = _interposed(public, inner)
        if msg:
            raise BadInput(f"{p}: [interpose] {public!r} = {inner!r}: {msg}")
        out[_expand(public, run, cell)] = _expand(inner, run, cell)
    return out


def _pose(v: list) -> str | None:
    if not finite_numbers(v, 6):
        return "must be 6 finite numbers: x y z [mm] A B C [ZYZ deg]"
    return None


def load_cell(path: str | os.PathLike | None = None) -> Cell:
    """Read and validate a cell file (default: $DROID_CELL or the built-in sim cell)."""
    p = Path(path) if path is not None else default_cell_path()
    return parse_cell(read_toml(p, "cell file"), p)


def parse_cell(raw: dict[str, Any], p: Path) -> Cell:
    try:
        # every number of the file -- [cell], [world] and its devices, every subunit's table --
        # finite and inside its key's range (droid.numbers, issue 16); the readers of each
        # table check their keys' types and tighter ranges after this
        check_numbers(raw)
    except NumberError as exc:
        raise BadInput(f"{p}: {exc}") from None
    top = _Reader(p, "top level", raw)
    name, hb_hz, stale, fifo, run_dir, layout, share = _cell_table(p, top)
    run = run_dir

    b = _Reader(p, "brain", top.get("brain", dict, {}))
    brain_host = b.get("host", str, "localhost")
    heartbeat = _expand(b.get("heartbeat", str, "ipc://{run}/heartbeat", check=_endpoint), run, name)
    names = _expand(b.get("names", str, "ipc://{run}/names", check=_endpoint), run, name)
    remotes = b.get("remotes", str, REMOTES_EACH, check=lambda v: None if v in (REMOTES_EACH, REMOTES_ONE)
                    else f'must be "{REMOTES_EACH}" (one droid-remote a subunit) or "{REMOTES_ONE}"')
    b.done()

    w = _Reader(p, "world", top.get("world", dict, {}))
    world = {"enabled": w.get("enabled", bool, True), "host": w.get("host", str, brain_host)}
    world.update(_expand(w.done(allow_extra=True), run, name))

    r2 = _Reader(p, "ros2", top.get("ros2", dict, {}))  # droid-ros2 (docs/ros2.md)
    ros2_domain = r2.get("domain_id", int, None,
                         check=lambda v: None if 0 <= v <= 232 else "must be a ROS 2 domain id in [0, 232]")
    r2.done()

    curve_table = top.get("curve", dict, None)
    top.get("guard", dict, None)  # the collision guard's table: read by droid.guard.cell (docs/guard.md)
    interpose = _interpose_table(top.get("interpose", dict, {}), p, run, name)

    subs_raw = top.get("subunits", dict)
    if not subs_raw:
        raise BadInput(f"{p}: [subunits] names no subunit")
    subunits: dict[str, Subunit] = {}
    for sname, table in subs_raw.items():
        subunits[sname] = _subunit(p, sname, table, brain_host, run, name)
    top.done(allow_extra=False)
    _check_programs(p, subunits)
    curve = None
    if curve_table is not None:
        hosts = sorted({brain_host, str(world["host"])} | {s.host for s in subunits.values()})
        curve = parse_curve_table(curve_table, p, hosts, lambda v: _expand(v, run, name))
    return Cell(path=p.resolve(), name=name, heartbeat_hz=hb_hz, stale_ticks=stale,
                sched_fifo=fifo, run_dir=Path(run_dir), brain_host=brain_host,
                heartbeat=heartbeat, names=names, world=world, subunits=subunits,
                curve=curve, raw=raw, interpose=interpose,
                layout=_layout_path(p, layout), remotes=remotes, share=share, ros2_domain=ros2_domain)


def _cell_table(p: Path, top: "_Reader") -> tuple:
    """``[cell]``: name, heartbeat rate [Hz], stale_ticks, sched_fifo, run_dir, layout and share."""
    c = _Reader(p, "cell", top.get("cell", dict))
    name = c.get("name", str)
    try:
        check_name_part(name, "cell")
    except BadInput as exc:
        raise BadInput(f"{p}: [cell] {exc}") from None
    hb_hz = c.get("heartbeat_hz", float, _registry.program("droid-heartbeat").rate_hz, check=_positive)
    lo, hi = HEARTBEAT_HZ_RANGE
    if not lo <= hb_hz <= hi:
        raise BadInput(f"{p}: [cell] heartbeat_hz {hb_hz:g} is outside [{lo:g}, {hi:g}] Hz")
    stale = c.get("stale_ticks", int, LIVENESS_TICKS, check=lambda v: None if v >= 1 else "must be >= 1")
    fifo = c.get("sched_fifo", bool, False)
    run_root = os.environ.get(ENV_RUN_ROOT, DEFAULT_RUN_ROOT)
    run_dir = c.get("run_dir", str, f"{run_root}/{name}")
    layout = c.get("layout", str, None)
    share = tuple(c.get("share", list, [], check=_shareable))
    c.done()
    return name, hb_hz, stale, fifo, run_dir, layout, share


def _shareable(progs: list) -> str | None:
    """``[cell] share``: programs that serve several subunits from one process (issue 28 item 4)."""
    reg = _registry.registry()
    ok = sorted(p.name for p in reg.programs.values() if p.several and p.role == "cell")
    for prog in progs:
        if not isinstance(prog, str) or prog not in reg.programs or not reg.programs[prog].several \
                or reg.programs[prog].role != "cell":
            return f"{prog!r} cannot serve several subunits from one process (those that can: {', '.join(ok)})"
    if len(set(progs)) != len(progs):
        return "names a program twice"
    return None


def _subunit(p: Path, sname: str, table, brain_host: str, run: str, name: str) -> Subunit:
    """One ``[subunits.NAME]`` table: its class, host, endpoints, programs, robot and base pose;
    the keys its class reads stay in ``options``."""
    try:
        check_name_part(sname, "subunit")
    except BadInput as exc:
        raise BadInput(f"{p}: [subunits] {exc}") from None
    r = _Reader(p, f"subunits.{sname}", table)
    reg = _registry.registry()
    cls = r.get("class", str, check=lambda v: None if v in reg.classes else
                reg.unknown("class", v, reg.classes))
    sub = Subunit(
        name=sname,
        cls=cls,
        host=r.get("host", str, brain_host),
        agent=_expand(r.get("agent", str, f"ipc://{{run}}/{sname}.agent", check=_endpoint), run, name),
        relay=_expand(r.get("relay", str, f"ipc://{{run}}/{sname}.relay", check=_endpoint), run, name),
        programs=r.get("programs", list, []),
        robot=r.get("robot", str, None),
        base=[float(v) for v in r.get("base", list, [0.0] * 6, check=_pose)],
        description=r.get("description", str, ""),
    )
    for prog in sub.programs:
        if not isinstance(prog, str):
            raise BadInput(f"{p}: [subunits.{sname}] programs must be a list of program names")
    if sub.is_arm and not sub.robot:
        raise BadInput(f"{p}: [subunits.{sname}] an {sub.cls} subunit needs 'robot'")
    sub.options = _expand(r.done(allow_extra=True), run, name)
    return sub


def _layout_path(p: Path, layout: str | None) -> Path | None:
    """[cell] layout: relative to the cell file's folder, or a bundled layout's name
    (:func:`find_file`).  A missing file is refused."""
    if layout is None:
        return None
    found = find_file(layout, p.resolve().parent)
    if found is None:
        raise BadInput(f"{p}: [cell] layout {layout!r}: no such file beside the cell file or among the bundled cells")
    return found


def _check_programs(p: Path, subunits: dict[str, Subunit]) -> None:
    """Every program a subunit names is registered (droid.brain.cell.registry.validate_cell checks
    more -- that it serves the subunit's class, that its module is there -- before a start)."""
    reg = _registry.registry()
    for s in subunits.values():
        for prog in s.programs:
            if prog not in reg.programs:
                raise BadInput(f"{p}: [subunits.{s.name}] {reg.unknown('program', prog, _registry.cell_programs(s.cls))}")
