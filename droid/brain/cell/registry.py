"""The device registry: every device class, program, driver and twin, declared once (docs/design.md §11).

A *device package* (one sub-package of ``droid.subunits`` with its twin beside
it in ``droid.sim``) declares in ONE module of its own -- ``device.py`` --
one :class:`DevicePackage`:

* the subunit classes it defines (:class:`~droid.brain.cell.classes.SubunitClass`:
  layouts, copied and snooped fields) and the classes it *serves* -- a class is
  an interface, not a package: ``arm6r`` (thesis Tables 3.1-3.2) is defined by
  the Brain and served by the Reis and the GMF1 program sets alike;
* its programs (:class:`Program`: console name, module, rate [Hz], scheduling
  class ``fifo``/``other`` with its priority, start group);
* its drivers (:class:`Driver`: a driver kind, the URL schemes it takes and
  its opener, all opened through :func:`open_url`, as pyserial's
  ``serial_for_url``);
* its world twins (:class:`Twin`: ``[world.devices.X] type`` -> factory);
* its lockstep builder (``"module:function"``, or None): ``build(ctx, sub) -> LockstepSubunit``,
  declared with the programs it has stations for (``@builds("droid-x", ...)``), which puts one
  subunit's stations and twin on a lockstep scheduler and returns its Brain Status/Command
  records (the protocol: :mod:`droid.sim.lockstep_build`; a whole cell file:
  ``droid.sim.lockstep_cell.build_lockstep_cell``, ``droid-sim lockstep CELL``).

Built-in packages are the one table :data:`BUILTIN_PACKAGES`; a package
outside the repository registers through the entry-point group
``droid.devices`` (python-can's ``can.interface``)::

    [project.entry-points."droid.devices"]
    labsensor = "labsensor.device:PACKAGE"

Every reference is a lazy ``"module:attr"`` string (python-can's
``BACKENDS``): this module imports nothing of ``droid.subunits`` or
``droid.sim``; a device package's module is imported when the registry is
first read, a program's, driver's or twin's module only when it is used.

``classes()`` (class name -> SubunitClass), ``droid.programs.PROGRAMS``,
``droid.sim.world.DEVICE_TYPES``, ``droid.brain.runtime.rt.FIFO_PRIORITIES`` and
``droid.brain.db.layouts.LAYOUTS`` (the layouts of packages outside the
repository are added to it) are views of this registry.
:func:`validate_cell` is what ``droid-cell up`` and ``droid-sim`` check before
they start anything (docs/architecture.md "Adding a device class").
"""
from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from dataclasses import dataclass
from typing import Any, Callable, Iterable
from urllib.parse import urlsplit

from droid.brain.cell.classes import SubunitClass
from droid.cli import BadInput

#: The entry-point group of device packages outside the repository.
ENTRY_POINT_GROUP = "droid.devices"

#: The built-in device packages, in registration order: name -> "module:attr" of its
#: :class:`DevicePackage` (imported when the registry is first read).
BUILTIN_PACKAGES: dict[str, str] = {
    "brain": "droid.brain.cell.device:PACKAGE",
    "reis": "droid.subunits.reis.device:PACKAGE",
    "gmf1": "droid.subunits.gmf1.device:PACKAGE",
    "mvs": "droid.subunits.mvs.device:PACKAGE",
    "joystick": "droid.subunits.joystick.device:PACKAGE",
    "ft": "droid.subunits.ft.device:PACKAGE",
    "abb": "droid.subunits.abb.device:PACKAGE",
}

SCHED_CLASSES = ("fifo", "nice", "other")
#: SCHED_FIFO priorities a program may declare: below the databases' priority ceiling
#: (droid.brain.runtime.rt.CEILING_PRIORITY = 61), which must outrank every program.
FIFO_PRIORITY_RANGE = (1, 60)
#: Start groups of the launcher: group 0 (name space, world) is ready before group 1 starts.
START_GROUPS = (0, 1)


@dataclass(frozen=True)
class Program:
    """One program: ``name`` is its console script, ``module`` has ``main(argv=None) -> int``.

    ``rate_hz``: its loop rate [Hz] (None: tick-driven or on request) -- the one place a
    rate like the servo's 500 Hz or the heartbeat's 60 Hz is written.  ``sched``:
    ``"fifo"`` (SCHED_FIFO at ``priority`` in a cell with ``sched_fifo = true``), ``"nice"``
    (the normal scheduler at nice :data:`droid.brain.runtime.rt.NICE_LEVEL` in such a cell: a program
    whose deadline is a heartbeat tick or longer and which feeds no servo, so it weighs
    ~10x a normal-priority process without drawing on the kernel's real-time budget;
    docs/architecture.md "Real time") or ``"other"``.  ``start``: the launcher's start group (0 before 1).  ``role``:
    ``"cell"`` (a subunit's ``programs`` may name it), ``"brain"`` (the launcher starts
    it for the Brain or the world) or ``"tool"`` (run by hand; never started by a cell).
    """

    name: str
    module: str
    rate_hz: float | None = None
    sched: str = "other"
    priority: int | None = None
    start: int = 1
    role: str = "cell"
    description: str = ""
    # what it costs a host: its share of one core [%] in an idle cell, and its resident
    # memory [MB], measured on the reference host (2-vCPU VM; bench/bench_footprint.py,
    # docs/benchmarks.md "Scale"); droid-cell up sums them per cell (issue 28: it warns when a
    # cell asks for more than the host can carry).  A program left at 0 counts as free.
    cpu_pct: float = 0.0
    rss_mb: float = 0.0
    # it serves several subunits from one process (``PROG NAME...``), so a cell's ``[cell]
    # share`` may start one per host for all of them (issue 28 item 4); ``cpu_pct_each``: what
    # each subunit past the first adds to that process [% of one core, idle], measured likewise
    several: bool = False
    cpu_pct_each: float = 0.0


@dataclass(frozen=True)
class Driver:
    """A driver kind (``vme``, ``serial``, ...): the URL schemes it takes and its opener.

    ``opener`` is ``"module:function"``, called as ``function(url, **options)``.  The
    scheme ``""`` stands for a plain path (a serial device ``/dev/ttyS0``)."""

    kind: str
    schemes: tuple[str, ...]
    opener: str
    forms: str = ""  # the URL forms, for messages


@dataclass(frozen=True)
class Twin:
    """A world twin: ``[world.devices.X] type = TYPE`` -> ``factory(world, name, options)``.

    ``serves``: the subunit classes it stands in for (empty: infrastructure, e.g. a cable)."""

    type: str
    factory: str  # "module:function"
    serves: tuple[str, ...] = ()
    cpu_pct: float = 0.0  # what one of it adds to droid-sim's share of one core [%] (as Program's)


@dataclass(frozen=True)
class DevicePackage:
    """What a device package declares, once, in its ``device.py`` (see the module docstring)."""

    name: str
    description: str = ""
    classes: tuple[SubunitClass, ...] = ()  # classes this package defines
    serves: tuple[str, ...] = ()  # classes defined elsewhere that its programs serve
    programs: tuple[Program, ...] = ()
    drivers: tuple[Driver, ...] = ()
    twins: tuple[Twin, ...] = ()
    # "module:function": build(ctx, sub) -> LockstepSubunit, one subunit in lockstep (droid.sim.lockstep_build)
    lockstep: str | None = None
    # (name, "module:class") pairs: the models a lockstep seam-tracking trial makes of its subunits
    # besides the built ones (docs/experiments.md): a lighter arm in the welder's place, named by the
    # trial's ``arm`` and made as ``cls(model, q_start_deg, params)`` (params: the trial's, None for
    # its own defaults; the Reis's "fast": its planner and one second-order loop a joint); "holder":
    # the workpiece holder over the built subunit, made as ``cls(sched, built, q_hold_deg)``, its
    # world ``cls.trial_world(subunit)`` (the GMF1's); "lead": the truth sensors of the layout's
    # ``sensor``, made as ``cls(workpiece, model, noise, seed=, frames_per_read=)`` -- ``cls.models``
    # the sensor models it has (a trial's ``sensor``), ``noise`` its own kind or None for its default;
    # ``read(T_W_S)`` the line the Brain's parser reads (or None: no line), ``frames``/``valid`` its
    # counts, ``tool_tip(noisy, seed)`` the tool-tip sensor beside it (``read(T_W_tool)``, and
    # ``truth(T_W_tool)``, exact: the trial's seam progress) (the MVS's)
    lockstep_models: tuple[tuple[str, str], ...] = ()
    # "module:function" (cell, subunit) -> bool: does this subunit need a world twin when
    # [world] is enabled?  None: the default rule (:func:`drives_the_world`).
    needs_twin: str | None = None
    # "module:function" (cell, subunit) -> [(name, url, kind), ...]: the endpoints its programs bind
    # for that subunit beyond the cell's ZeroMQ ones, which droid-fault's proxy may interpose as
    # ``<subunit>.<name>`` (droid.faults.proxy: kind "udp"; the ABB's EGM address); [] for a subunit
    # not its own.  None: none.
    proxy_endpoints: str | None = None
    generic: bool = False  # its cell programs serve every class (droid-agent)

    def program(self, name: str) -> Program:
        for p in self.programs:
            if p.name == name:
                return p
        raise KeyError(f"package {self.name!r} declares no program {name!r}")

    def lockstep_model(self, name: str) -> str | None:
        """The ``"module:class"`` of its lockstep arm model ``name`` (``lockstep_models``), or None."""
        return dict(self.lockstep_models).get(name)

    @property
    def served(self) -> tuple[str, ...]:
        """Every class its programs and twins serve: those it defines and ``serves``."""
        return tuple(c.name for c in self.classes) + tuple(self.serves)


def resolve(ref: str) -> Any:
    """The object a lazy ``"module:attr"`` reference names (imported now)."""
    module, _, attr = ref.partition(":")
    obj = importlib.import_module(module)
    for part in attr.split(".") if attr else ():
        obj = getattr(obj, part)
    return obj


class RegistryError(BadInput):
    """A device package that cannot be registered (exit 2)."""


class Registry:
    """The merged declarations of every device package (built-in and entry points)."""

    def __init__(self) -> None:
        self.packages: dict[str, DevicePackage] = {}
        self.origin: dict[str, str] = {}  # package -> where it was declared
        self.classes: dict[str, SubunitClass] = {}
        self.class_package: dict[str, str] = {}  # class -> the package defining it
        self.programs: dict[str, Program] = {}
        self.program_package: dict[str, str] = {}
        self.drivers: dict[str, dict[str, Driver]] = {}  # kind -> scheme -> driver
        self.twins: dict[str, Twin] = {}
        self.twin_package: dict[str, str] = {}
        self.failed: list[str] = []  # entry points that could not be registered, one line each

    # -- building --------------------------------------------------------------------
    def add(self, pkg: DevicePackage, origin: str) -> None:
        """Register ``pkg``; RegistryError (and nothing registered) if it clashes or is malformed."""
        if not isinstance(pkg, DevicePackage):
            raise RegistryError(f"{origin}: is a {type(pkg).__name__}, not a droid.brain.cell.registry.DevicePackage")
        problems = list(self._problems(pkg))
        if problems:
            raise RegistryError(f"{origin}: package {pkg.name!r}: {problems[0]}")
        self.packages[pkg.name] = pkg
        self.origin[pkg.name] = origin
        for c in pkg.classes:
            self.classes[c.name] = c
            self.class_package[c.name] = pkg.name
        for p in pkg.programs:
            self.programs[p.name] = p
            self.program_package[p.name] = pkg.name
        for d in pkg.drivers:
            for s in d.schemes:
                self.drivers.setdefault(d.kind, {})[s] = d
        for t in pkg.twins:
            self.twins[t.type] = t
            self.twin_package[t.type] = pkg.name

    def _problems(self, pkg: DevicePackage) -> Iterable[str]:
        from droid.brain.db.layouts import LAYOUTS

        if pkg.name in self.packages:
            yield f"a package {pkg.name!r} is already registered ({self.origin[pkg.name]})"
        for c in pkg.classes:
            if c.name in self.classes:
                yield f"class {c.name!r} is already defined by package {self.class_package[c.name]!r}"
            if "status" not in c.brain or "ctrl_status" not in c.local:
                yield f"class {c.name!r} needs a Brain 'status' and a subunit 'ctrl_status' layout"
            for lay in (*c.brain.values(), *c.local.values()):
                known = LAYOUTS.get(lay.kind)
                if known is not None and known != lay:
                    yield f"class {c.name!r}: layout {lay.name!r} takes kind {lay.kind}, already {known.name!r}"
        for p in pkg.programs:
            if p.name in self.programs:
                yield f"program {p.name!r} is already declared by package {self.program_package[p.name]!r}"
            if p.sched not in SCHED_CLASSES:
                yield f"program {p.name!r}: sched {p.sched!r} is not one of {', '.join(SCHED_CLASSES)}"
            lo, hi = FIFO_PRIORITY_RANGE
            if p.sched == "fifo" and not (isinstance(p.priority, int) and lo <= p.priority <= hi):
                yield f"program {p.name!r}: a fifo program needs a priority in [{lo}, {hi}]"
            if p.start not in START_GROUPS:
                yield f"program {p.name!r}: start group {p.start!r} is not one of {START_GROUPS}"
            if p.role not in ("cell", "brain", "tool"):
                yield f"program {p.name!r}: role {p.role!r} is not cell, brain or tool"
            if p.rate_hz is not None and not p.rate_hz > 0:
                yield f"program {p.name!r}: rate_hz must be > 0 Hz"
        for d in pkg.drivers:
            for s in d.schemes:
                if s in self.drivers.get(d.kind, {}):
                    yield f"driver {d.kind} scheme {s!r}:// is already declared"
        served = set(pkg.served)
        for t in pkg.twins:
            if t.type in self.twins:
                yield f"twin type {t.type!r} is already declared by package {self.twin_package[t.type]!r}"
            for c in t.serves:
                if c not in served:
                    yield f"twin {t.type!r} serves class {c!r}, which the package neither defines nor serves"
        for c in pkg.serves:
            if c not in self.classes and c not in {k.name for k in pkg.classes}:
                yield f"serves class {c!r}, which no package registered before it defines"

    def add_ref(self, ref: str, origin: str) -> None:
        try:
            pkg = resolve(ref)
        except Exception as exc:  # an entry point that fails to import: one line, what is missing
            raise RegistryError(f"{origin}: cannot load {ref}: {type(exc).__name__}: {exc}") from None
        self.add(pkg, origin)

    # -- reading ---------------------------------------------------------------------
    def package_of_class(self, cls: str) -> list[DevicePackage]:
        """The packages that define or serve class ``cls``."""
        return [p for p in self.packages.values() if cls in p.served]

    def unknown(self, what: str, name: str, known: Iterable[str]) -> str:
        """``unknown <what> 'name' (known: ...)``, with the entry points that failed."""
        msg = f"unknown {what} {name!r} (known: {', '.join(known)})"
        if self.failed:
            msg += "; not loaded: " + "; ".join(self.failed)
        return msg

    def named(self, what: str, name: str, table: dict):
        """``table[name]``; else a KeyError saying :meth:`unknown` (the known names)."""
        try:
            return table[name]
        except KeyError:
            raise KeyError(self.unknown(what, name, table)) from None


def _entry_points():
    from importlib import metadata  # imported when the registry is first built (about 0.1 s)

    return metadata.entry_points(group=ENTRY_POINT_GROUP)


def _ep_origin(ep) -> str:
    dist = getattr(ep, "dist", None)
    where = ""
    if dist is not None:
        path = getattr(dist, "_path", None)
        where = f" ({os.path.join(str(path), 'entry_points.txt')})" if path is not None else f" ({dist.name})"
    return f"entry point {ENTRY_POINT_GROUP} {ep.name!r} = {ep.value!r}{where}"


_REGISTRY: Registry | None = None
# the views: one dict object each, refilled in place by reset(), so a module that
# imported one (from droid.programs import PROGRAMS) keeps seeing the registry
CLASSES_VIEW: dict[str, SubunitClass] = {}
PROGRAMS_VIEW: dict[str, str] = {}
DEVICE_TYPES_VIEW: dict[str, tuple[str, str]] = {}
FIFO_VIEW: dict[str, int] = {}
_ADDED_LAYOUTS: list[int] = []


def registry() -> Registry:
    """The registry (built on first use: the built-in table, then the entry points)."""
    global _REGISTRY
    if _REGISTRY is None:
        reg = Registry()
        for name, ref in BUILTIN_PACKAGES.items():
            reg.add_ref(ref, f"built-in package {name!r} ({ref})")
        seen = set()
        for ep in _entry_points():
            if ep.name in seen:  # the same distribution found twice on sys.path
                continue
            seen.add(ep.name)
            try:
                reg.add_ref(ep.value, _ep_origin(ep))
            except RegistryError as exc:
                reg.failed.append(str(exc))
        _REGISTRY = reg
        _fill_views(reg)
    return _REGISTRY


def _fill_views(reg: Registry) -> None:
    from droid.brain.db.layouts import LAYOUTS

    CLASSES_VIEW.clear()
    CLASSES_VIEW.update(reg.classes)
    PROGRAMS_VIEW.clear()
    PROGRAMS_VIEW.update({p.name: p.module for p in reg.programs.values()})
    DEVICE_TYPES_VIEW.clear()
    DEVICE_TYPES_VIEW.update({t.type: tuple(t.factory.split(":", 1)) for t in reg.twins.values()})
    FIFO_VIEW.clear()
    FIFO_VIEW.update({p.name: p.priority for p in reg.programs.values() if p.sched == "fifo"})
    for c in reg.classes.values():  # a package's own layouts join the table (droid-cheader, headers)
        for lay in (*c.brain.values(), *c.local.values()):
            if lay.kind not in LAYOUTS:
                LAYOUTS[lay.kind] = lay
                _ADDED_LAYOUTS.append(lay.kind)


def reset() -> None:
    """Forget the registry (tests that put a package on sys.path); rebuilt on next use."""
    global _REGISTRY
    from droid.brain.db.layouts import LAYOUTS

    _REGISTRY = None
    for kind in _ADDED_LAYOUTS:
        LAYOUTS.pop(kind, None)
    _ADDED_LAYOUTS.clear()
    for view in (CLASSES_VIEW, PROGRAMS_VIEW, DEVICE_TYPES_VIEW, FIFO_VIEW):
        view.clear()
    metadata_cache_clear()


def metadata_cache_clear() -> None:
    importlib.invalidate_caches()


def classes() -> dict[str, SubunitClass]:
    """class name -> :class:`SubunitClass`: every class a cell file may name, whichever package
    defines it (one dict, refilled in place when the registry is rebuilt)."""
    registry()
    return CLASSES_VIEW


def programs() -> dict[str, str]:
    """program name -> module (the view ``droid.programs.PROGRAMS``)."""
    registry()
    return PROGRAMS_VIEW


def device_types() -> dict[str, tuple[str, str]]:
    """twin type -> (module, factory) (the view ``droid.sim.world.DEVICE_TYPES``)."""
    registry()
    return DEVICE_TYPES_VIEW


def fifo_priorities() -> dict[str, int]:
    """program -> SCHED_FIFO priority (the view ``droid.brain.runtime.rt.FIFO_PRIORITIES``)."""
    registry()
    return FIFO_VIEW


def program(name: str) -> Program:
    """The declaration of program ``name``; KeyError names the known ones."""
    reg = registry()
    return reg.named("program", name, reg.programs)


def layouts():
    """Every layout: the Brain's table plus those of every registered class (droid-cheader)."""
    from droid.brain.db.layouts import LAYOUTS

    registry()
    return LAYOUTS


def twin(typ: str) -> Twin:
    """The declaration of world twin ``typ``; KeyError if none is registered."""
    return registry().twins[typ]


def twin_factory(typ: str) -> Callable:
    """The factory of world twin ``typ`` (imported now); KeyError if none is registered."""
    return resolve(twin(typ).factory)


# -- the one URL opener (pyserial's serial_for_url) -----------------------------------
def url_scheme(url: str) -> str:
    """The scheme of ``url``; ``""`` for a plain path (``/dev/ttyS0``, ``{run}/gmf1.tty``)."""
    return urlsplit(url).scheme if isinstance(url, str) and "://" in url else ""


def open_url(url: str, kind: str, **options) -> Any:
    """Open ``url`` with the driver of ``kind`` a package declared for its scheme.

    ``kind`` says which device the URL names (``vme``, ``encoder_card``, ``dsp``,
    ``serial``, ``joystick``, ...): one scheme (``shm://``) serves several kinds.
    The driver's opener is called as ``opener(url, **options)`` and returns what it
    returns (a bus, a board, a port opener, a device).  An unknown kind or scheme is a
    BadInput naming the known ones."""
    reg = registry()
    table = reg.drivers.get(kind)
    if table is None:
        raise BadInput(reg.unknown("driver kind", kind, sorted(reg.drivers)))
    scheme = url_scheme(url)
    drv = table.get(scheme)
    if drv is None:
        known = ", ".join(f"{s}://" if s else "a device path" for s in table)
        forms = f"; expected {next(iter(table.values())).forms}" if next(iter(table.values())).forms else ""
        raise BadInput(f"{kind} URL {url!r}: unknown scheme {scheme!r} (known: {known}){forms}")
    return resolve(drv.opener)(url, **options)


# -- checking a cell before anything starts --------------------------------------------
def drives_the_world(cell, sub) -> bool:
    """The default answer to "does this subunit need a world twin?": one of its options is a
    URL or path the world makes -- an ``shm://``/``inproc://`` device or a path inside the
    cell's run directory that is no ZeroMQ endpoint (a pseudo-terminal, a device file)."""
    run = str(cell.run_dir).rstrip("/") + "/"

    def simulated(v: Any) -> bool:
        if isinstance(v, list):
            return any(simulated(x) for x in v)
        if not isinstance(v, str):
            return False
        scheme = url_scheme(v)
        if scheme in ("shm", "inproc"):
            return True
        if scheme in ("ipc", "tcp"):
            return False
        path = urlsplit(v).path if scheme else v
        return path.startswith(run)

    return any(simulated(v) for v in sub.options.values())


def validate_cell(cell) -> None:
    """Check a parsed cell against the registry before anything starts (``droid-cell up``,
    ``droid-sim``): every subunit's class and programs are registered, its programs serve its
    class and their modules exist, a subunit that needs a world twin has one.  BadInput with
    one line naming the cell file, the subunit and what is missing."""
    reg = registry()
    p = cell.path
    for sub in cell.subunits.values():
        where = f"{p}: [subunits.{sub.name}]"
        if sub.cls not in reg.classes:
            raise BadInput(f"{where} class: {reg.unknown('class', sub.cls, reg.classes)}")
        for prog in sub.programs:
            decl = reg.programs.get(prog)
            if decl is None:
                raise BadInput(f"{where} {reg.unknown('program', prog, cell_programs(sub.cls))}")
            owner = reg.packages[reg.program_package[prog]]
            if decl.role != "cell":
                raise BadInput(f"{where} program {prog!r} is a {decl.role} program, not a subunit's")
            if not owner.generic and sub.cls not in owner.served:
                raise BadInput(f"{where} program {prog!r} (package {owner.name!r}) serves "
                               f"{', '.join(owner.served) or 'no class'}, not class {sub.cls!r}")
            if not _module_exists(decl.module):
                raise BadInput(f"{where} program {prog!r}: its module {decl.module!r} is not installed "
                               f"(package {owner.name!r}, {reg.origin[owner.name]})")
        if cell.world.get("enabled", True) and _needs_twin(reg, cell, sub):
            twins = [t.type for t in reg.twins.values() if sub.cls in t.serves]
            if not twins:
                pkgs = ", ".join(repr(k.name) for k in reg.package_of_class(sub.cls)) or "none"
                raise BadInput(f"{where} class {sub.cls!r} has no world twin (package {pkgs} declares "
                               f"none) but [world] is enabled and the subunit's devices are simulated; "
                               f"declare a twin or set [world] enabled = false")


def cell_programs(cls: str) -> list[str]:
    """The programs a subunit of class ``cls`` may run (its packages' and the generic ones)."""
    reg = registry()
    return [n for n, pr in reg.programs.items() if pr.role == "cell"
            and (reg.packages[reg.program_package[n]].generic
                 or cls in reg.packages[reg.program_package[n]].served)]


def _needs_twin(reg: Registry, cell, sub) -> bool:
    for pkg in reg.package_of_class(sub.cls):
        if pkg.needs_twin is not None:
            if resolve(pkg.needs_twin)(cell, sub):
                return True
        elif drives_the_world(cell, sub):
            return True
    return False


def _module_exists(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def describe() -> list[str]:
    """One line per package (``python -m droid.brain.cell.registry``)."""
    reg = registry()
    out = []
    for pkg in reg.packages.values():
        out.append(f"{pkg.name}: classes {', '.join(c.name for c in pkg.classes) or '-'}; "
                   f"serves {', '.join(pkg.serves) or '-'}; programs {len(pkg.programs)}; "
                   f"drivers {', '.join(sorted({d.kind for d in pkg.drivers})) or '-'}; "
                   f"twins {', '.join(t.type for t in pkg.twins) or '-'}; lockstep {pkg.lockstep or '-'}")
    out.extend(f"not loaded: {f}" for f in reg.failed)
    return out


if __name__ == "__main__":  # run as a script this module is __main__: read the real one
    from droid.brain.cell import registry as _self

    print("\n".join(_self.describe()))
    sys.exit(0)
