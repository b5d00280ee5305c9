"""The lockstep slot of a device package: one builder a package, one subunit a call (docs/design.md §2, §11).

A device package's ``DevicePackage.lockstep`` names ``"module:function"``, a **builder**::

    @builds("droid-joystick", "droid-agent")       # the programs it gives stations for
    def build(ctx: BuildContext, sub: Subunit) -> LockstepSubunit: ...

called once per subunit of a class the package serves, as Drake's ``DiagramBuilder.AddSystem``
adds a system: it puts the subunit's stations (the same read -> core.step -> write cycles as its
real-time programs, :mod:`droid.sim.lockstep`) and its twin on ``ctx.sched`` and returns the
subunit as a task program sees it.  ``ctx`` carries the scheduler, the cell, the seed, the world
devices built so far by name (``ctx.twins``: an F/T sensor or a camera finds the arm it sits on or
looks at there) and the subunits built so far (``ctx.built``); arms are built before everything
else, and ``ctx.after(fn)`` defers what needs every twin (a contact between two arms).  :func:`droid.sim.lockstep_cell.build_lockstep_cell` picks the builder of each subunit by its
programs: the builder of a package serving its class whose ``programs`` hold every program the
subunit runs (so the ABB's, which stands for ``droid-reis-agent`` and ``droid-planner`` beside its
``droid-egm``, builds an ABB arm, and the Reis's a Reis arm).

The result, :class:`LockstepSubunit`, exposes the subunit's Brain databases as real time has them
in shared memory (``status``, ``command``: :class:`~droid.brain.db.shmdb.MemoryDatabase` of the same
layouts, the class's ``brain`` table), its stations (program -> scheduler task names) and, for an
arm, what a task program drives (``arm``: :class:`droid.arm.protocol.Arm`, as ``BrainArm``).

:class:`AgentLink` is the generic ``droid-agent`` / ``droid-remote`` pair on the heartbeat tick
(thesis §3.2, §4.1.8): the Brain Command copied into the subunit's ``ctrl_command`` (if its class
has one), its ``ctrl_status`` replied into the Brain Status; a sensor's builder writes its
``ctrl_status`` and adds this link.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from droid.arm.protocol import Arm
from droid.brain.db.databases import safe_start
from droid.brain.runtime.remote import RemoteStation, StatusTranslator
from droid.brain.db.shmdb import MemoryDatabase
from droid.sim.lockstep import ORDER_HEARTBEAT, Scheduler
from droid.subunits.agent import AgentStation, CommandCopier

#: The generic subunit server (droid.brain.cell.device): a sensor's builder names it among its programs.
AGENT = "droid-agent"


def builds(*programs: str, check: Callable | None = None, truth: bool = False) -> Callable:
    """Declare the programs a lockstep builder gives stations for (see the module docstring);
    ``check(cell, sub)``: what the builder refuses, asked without building anything (BadInput, one
    line) -- a task that builds later (a seam-tracking trial) refuses a bad cell before it runs;
    ``truth``: the arm it builds also shows the world's truth about itself, ``wcp_global()`` (the
    true wrist-centre pose, 4x4 mm, global frame), so a trial can carry its tool on it (the
    layout's tool_robot: the sensors see the seam from its true pose)."""
    def mark(fn: Callable) -> Callable:
        fn.programs = tuple(programs)
        fn.check = check if check is not None else (lambda cell, sub: None)
        fn.truth = bool(truth)
        return fn
    return mark


def brain_databases(sub) -> dict[str, MemoryDatabase]:
    """The subunit's Brain records (area -> MemoryDatabase of its class's layout), command records
    with the safe start values of ``droid.brain.db.databases.create_databases`` (JOG, joint space)."""
    return {area: _fresh(f"{sub.name}.{area}", lay) for area, lay in sub.kind.brain.items()}


def local_databases(sub) -> dict[str, MemoryDatabase]:
    """The subunit side's records (``ctrl_status``, ``ctrl_command`` if its class has one)."""
    return {area: _fresh(f"{sub.name}.{area}", lay) for area, lay in sub.kind.local.items()}


def _fresh(name: str, layout) -> MemoryDatabase:
    db = MemoryDatabase(name, layout)
    safe_start(db)
    return db


@dataclass
class LockstepSubunit:
    """One subunit on the scheduler: its Brain records, its stations and (arms) its task interface.

    ``status``/``command``: the Brain's Status and Command records (``command`` None for a class
    without one); ``stations``: program -> the scheduler task names that stand for it (a tick task
    included); ``arm``: for an arm the object a task program drives, the neutral arm's
    :class:`droid.arm.protocol.Arm` (``home() -> bool``, ``command_joint``, ``command_cart``, ``read``,
    ... as ``BrainArm``), None for a sensor; ``parts``: the package's own
    lockstep object (LockstepArm, Gmf1Lockstep, ...) for inspection and fault injection."""

    name: str
    cls: str
    status: MemoryDatabase
    command: MemoryDatabase | None = None
    stations: dict[str, list[str]] = field(default_factory=dict)
    arm: Arm | None = None
    parts: Any = None

    def close(self) -> None:
        close = getattr(self.parts, "close", None)
        if callable(close):
            close()


@dataclass
class BuildContext:
    """What a builder gets besides its subunit: the scheduler, the cell, the seed (the world's
    ``[world] seed`` unless overridden), the world devices built so far (name -> object with the
    world's arm interface, ``wcp_global()`` 4x4 mm) and the subunits built so far.

    ``world``: a ``[world]`` table the builders read instead of the cell's (``rate_hz`` and the
    ``devices`` tables, :attr:`world_hz` and :meth:`world_devices`): a task that brings its own
    world.  A seam-tracking trial builds its welder and holder so (its holder model's
    ``trial_world``, droid.sim.gmf1.holder.Gmf1Holder.trial_world): no ``reis_vme`` table for its Reis (no world errors, no contacts: the arm the trial
    always ran, on the trial's seed), its GMF1 homing from the zero pose through a dynamic KAREL
    twin at the trial's world rate.  A twin that *is* its subunit's controller (the ABB's
    ``abb_egm``) is still read from the cell by its builder."""

    sched: Scheduler
    cell: Any  # droid.brain.cell.cellfile.Cell
    seed: int
    world: dict | None = None
    twins: dict[str, Any] = field(default_factory=dict)
    built: dict[str, LockstepSubunit] = field(default_factory=dict)
    finish: list[Callable[[], None]] = field(default_factory=list)

    def after(self, fn: Callable[[], None]) -> None:
        """Call ``fn()`` once every subunit is built (a world device between two subunits' twins:
        the Reis's ``contact`` device, whose workpiece the holder arm carries)."""
        self.finish.append(fn)

    def where(self, sub) -> str:
        """``FILE: [subunits.NAME]``, the head of a one-line refusal."""
        return f"{self.cell.path}: [subunits.{sub.name}]"

    def rate_hz(self, program: str) -> float | None:
        """The rate [Hz] program ``program`` declares in the registry (None: tick-driven)."""
        from droid.brain.cell.registry import program as declared

        return declared(program).rate_hz

    @property
    def _world(self) -> dict:
        return self.cell.world if self.world is None else self.world

    @property
    def world_hz(self) -> float:
        """The world's step rate [Hz]: the cell's ``[world] rate_hz`` (droid-sim's default 1 kHz)."""
        return float(self._world.get("rate_hz", self.rate_hz("droid-sim")))

    def world_devices(self, typ: str) -> dict[str, dict]:
        """The ``[world.devices.*]`` tables of ``type = typ`` (name -> options without type): the
        cell's, or those of the context's own ``world``."""
        return {n: {k: v for k, v in o.items() if k != "type"} for n, o in self._world.get("devices", {}).items()
                if isinstance(o, dict) and o.get("type") == typ}


class AgentLink:
    """``droid-agent`` and ``droid-remote`` of one subunit on the heartbeat tick (thesis §3.2, §4.1.8).

    Each tick (at ``order``, after the subunit's own stations wrote): the remote's silence rule and
    tick, the agent's copy of the Brain Command into ``ctrl_command`` (a class with one), the reply:
    ``ctrl_status`` translated into the Brain Status (its class's ``copy_fields``)."""

    def __init__(self, ctx: BuildContext, sub, brain: dict, local: dict, order: int = ORDER_HEARTBEAT) -> None:
        sched = ctx.sched
        self.sched = sched
        self.ctrl_status = local["ctrl_status"]
        ctrl_command = local.get("ctrl_command")
        command = brain.get("command")
        copier = CommandCopier.for_subunit(ctrl_command, sub) if ctrl_command is not None else None
        self.agent = AgentStation(self.ctrl_status, ctrl_command, ctx.cell.period_ns, ctx.cell.stale_ticks, copier)
        self.remote = RemoteStation(brain["status"], command if ctrl_command is not None else None,
                                    StatusTranslator(sub.name, sub.kind), ctx.cell.stale_ticks, sched.heartbeat_hz)
        self.task = f"{sub.name}.agent_link"
        sched.on_tick(self._tick, self.task, order=order)

    def _tick(self, tick: int) -> None:
        t_ns = self.sched.t_ns
        self.remote.on_poll(t_ns)
        self.remote.on_tick(tick, t_ns)
        reply = self.agent.on_command(self.remote.command_payload(), tick, t_ns)
        self.remote.on_reply(tick, reply, t_ns)
