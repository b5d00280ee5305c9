"""The lockstep trial cell (issue 43 item 2, thesis §6.1): a seam-tracking trial's cell, checked by role,
its geometry at the start, its welder and holder built and started in order -- the set-up below the
experiments, handed plain values (a cell file or Cell, an arm model's name, a seed, ...), never a trial's
config.  Its cell is ``TrialConfig.cell``, ``droid-experiment run --cell FILE``, a plan's ``cell``, or
the built-in cell.

The trial reads the cell's seam-tracking layout (its ``[cell] layout``, else the bundled one:
droid.brain.cell.cell_layout.layout_for_cell); the welder is the subunit its layout names by role,
``tool_robot``, the holder ``holder_robot``, both subunits of the cell at the cell's bases with the
layout's robot files.  Both are chosen through the registry, by what they are, never by brand:
the builder a device package registers in the ``lockstep`` slot (droid.sim.lockstep_cell.choose_builder,
by the programs the subunit runs), which must stand for no program the subunit does not run (the
builder's own ``@builds``):

* the welder's: any arm builder declared with ``truth`` (:func:`welder_builders`: its arm shows the
  world's truth about its wrist centre, so the sensors see the seam from it) -- today the Reis's
  (:class:`droid.sim.reis.cell.LockstepArm`) and the ABB's on EGM
  (:class:`droid.sim.abb.lockstep.LockstepAbbArm`, its ``abb_egm`` world device: its controller), or a
  lab's own package's;
* the holder's (``holder = "gmf1"``: the holder robot through its own controller), any builder
  whose package registers a ``holder`` lockstep model (:func:`holder_builders`: the GMF1's,
  droid.sim.gmf1.holder.Gmf1Holder);
* anything else: one line naming the file, the subunit and what a lockstep arm needs.

:func:`resolve_trial_cell` reads and checks all of it once, before anything runs, into a
:class:`TrialCell`, whose :meth:`TrialCell.build_arms` builds each subunit with its builder
through the lockstep cell builder (droid.sim.lockstep_cell.build_lockstep_cell, LockstepCell.add:
the welder, homed, then the holder -- the trial's start order) with the trial's seed, the cell's ``stale_ticks`` and
the trial's own world (its holder model's ``trial_world``: the holder's twin alone) instead of the
cell's world-device tables.  The truth sensors -- the lead sensor and the tool-tip sensor beside
it -- are those of the layout's ``sensor``, a subunit of the cell whose package registers a
``lead`` lockstep model (:func:`sensor_packages`, :meth:`TrialCell.lead_sensor`: the MVS's,
droid.sim.mvs.trial_sensors).  :func:`trial_geometry` places the layout's position, workpiece and wrist
(:class:`TrialGeometry`: where everything is at the start); :class:`FullArm` is the ``full`` arm model over
the welder its builder builds (homed, then moved to the start pose).  A trial
without a cell file runs on the built-in cell (droid/cells/sim.toml, whatever $DROID_CELL says;
:func:`builtin_cell`): the Reis ``arm1`` and the GMF1 ``gmf1``.

An arm model other than ``full`` is one the welder's device package registers
(``DevicePackage.lockstep_models``: the Reis's ``fast``, droid.sim.reis.fast_arm, calibrated against
its servo and plant); a welder whose package registers none is refused.  The GMF1's holder model
drives the GMF1 with the cell's serial and encoder set-up (droid.sim.gmf1.holder).  The trial runs
at the heartbeat of droid.brain.cell.device.HEARTBEAT_HZ (its 30 Hz cycle is 2 ticks): a cell of another rate is refused.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from droid.brain.cell.cellfile import BUNDLED_CELLS, Cell, builtin_cell_path, find_file, load_cell
from droid.brain.cell.device import HEARTBEAT_HZ
from droid.brain.plumbing.wire import LIVENESS_TICKS
from droid.cli import BadInput, RuntimeFailure
from droid.brain.cell.cell_layout import Layout, Wrist, check_bases, check_robots, layout_for_cell, load_layout
from droid.kinematics import RobotModel, Unreachable, load_robot
from droid.kinematics.transforms import inv_homo, record_pose
from droid.sim.lockstep import Scheduler
from droid.sim.workpiece import Workpiece, load_workpiece



def welder_builders(cell: Cell, sub) -> dict:
    """The lockstep builders whose arm the ``full`` model can drive as ``sub``'s tool robot, by the
    name of the package that registers each: of the packages serving its class, every builder
    declared with ``truth`` (droid.sim.lockstep_build.builds: an Arm that also shows the world's
    ``wcp_global``).  What their subunits run is the builders' own ``@builds``."""
    from droid.sim.lockstep_cell import class_builders

    return {build: name for name, build in class_builders(cell, sub) if getattr(build, "truth", False)}


def holder_builders(cell: Cell, sub) -> dict:
    """The lockstep builders that can build ``sub`` as the trial's workpiece holder, by the name of
    the package that registers each: of the packages serving its class, those that register a
    ``holder`` lockstep model (DevicePackage.lockstep_models: the GMF1's, droid.sim.gmf1.holder)."""
    from droid.brain.cell.registry import registry
    from droid.sim.lockstep_cell import class_builders

    pkgs = registry().packages
    return {build: name for name, build in class_builders(cell, sub) if pkgs[name].lockstep_model("holder")}


def sensor_packages(cell: Cell, sub) -> list[str]:
    """The packages that can make the trial's truth sensors of ``sub``, the layout's ``sensor``, by
    name: of the packages serving its class, those that register a ``lead`` lockstep model
    (DevicePackage.lockstep_models: the MVS's, droid.sim.mvs.trial_sensors.LeadSensor), first
    those whose programs the subunit runs."""
    from droid.brain.cell.registry import registry

    pkgs = [p for p in registry().package_of_class(sub.cls) if p.lockstep_model("lead")]
    runs = set(sub.programs)
    return [p.name for p in sorted(pkgs, key=lambda p: not runs & {q.name for q in p.programs})]


def _model(package: str, name: str):
    """Package ``package``'s lockstep model ``name`` (its class), or None when it registers none."""
    from droid.brain.cell.registry import registry, resolve

    ref = registry().packages[package].lockstep_model(name)
    return resolve(ref) if ref is not None else None


def no_mark(phase: str, sched) -> None:
    """The phase hook of a trial cell that reports no phases (droid.experiments.phases.mark reports them)."""


@dataclass(frozen=True)
class TrialGeometry:
    """Frames of one trial (4x4, mm, global unless named otherwise)."""

    layout: Layout
    wrist: Wrist
    workpiece: Workpiece
    position: str
    tool: RobotModel  # the layout's tool robot (the welder: the Reis or the ABB), with its base
    holder: RobotModel  # the layout's holder robot, with its base
    T_global_W: np.ndarray
    T_hold6_W: np.ndarray  # (GMF1)6 T W, the mount
    T_global_hold6: np.ndarray  # GMF1 wrist centre (held still)
    q_hold_deg: np.ndarray
    T_global_tool6_start: np.ndarray  # the tool robot's wrist centre at the start
    q_tool_start_deg: np.ndarray

    @property
    def camera_to_tcp_mm(self) -> float:
        return self.wrist.camera_to_tcp_mm

    @property
    def T_W_global(self) -> np.ndarray:
        return inv_homo(self.T_global_W)


@lru_cache(maxsize=8)
def _robot(name: str, base_key: tuple) -> RobotModel:
    base = np.array(base_key, float).reshape(4, 4)
    return load_robot(name).with_base(base)


def robot_with_base(layout: Layout, subunit: str) -> RobotModel:
    """The robot model of a layout subunit, placed at its base."""
    name = layout.robots.get(subunit)
    if not name:
        raise BadInput(f"layout {layout.source}: [robots] names no model for {subunit}")
    return _robot(name, tuple(layout.base(subunit).ravel().tolist()))


def trial_geometry(position: str, workpiece: str | None = None, wrist: str = "standard",
                   layout: Layout | None = None) -> TrialGeometry:
    """The frames of a trial at ``position`` (i..vii) with ``workpiece`` (default: the position's)."""
    lay = layout or load_layout()
    pos = lay.position(position)
    wr = lay.wrist(wrist)
    wp = load_workpiece(workpiece or pos.workpiece)
    tool = robot_with_base(lay, lay.tool_robot)
    holder = robot_with_base(lay, lay.holder_robot)
    L = wr.camera_to_tcp_mm
    T_gW = pos.T_global_W(L)
    mount = lay.mount(wp.name)
    T_hold = T_gW @ inv_homo(mount)
    try:
        q_hold = holder.ik(T_hold, np.zeros(6))
    except Unreachable as exc:
        raise BadInput(f"position {position}: the {lay.holder_robot} cannot hold {wp.name} there: {exc}") from None
    T_tool = T_gW @ wp.seam_frame(-L)
    T_tool6 = T_tool @ inv_homo(wr.T_wcp_tool)
    try:
        q_tool = tool.ik(T_tool6, np.zeros(6))
    except Unreachable as exc:
        raise BadInput(f"position {position}: the {lay.tool_robot} cannot reach the start: {exc}") from None
    return TrialGeometry(layout=lay, wrist=wr, workpiece=wp, position=position, tool=tool, holder=holder,
                         T_global_W=T_gW, T_hold6_W=mount, T_global_hold6=holder.fk(q_hold), q_hold_deg=q_hold,
                         T_global_tool6_start=T_tool6, q_tool_start_deg=q_tool)


@dataclass(frozen=True)
class TrialCell:
    """A checked cell of a trial (thesis §6.1: the Reis welds, the GMF1 holds), resolved once by
    :func:`resolve_trial_cell`: the cell, its layout (which subunit welds, ``tool_robot``; which
    holds, ``holder_robot``), the lockstep builder of each subunit the trial builds, and the
    trial's own ``[world]`` table those builders read (the holder model's ``trial_world``; empty for a
    fixed holder)."""

    cell: Cell
    layout: Layout
    builders: dict  # subunit name -> its lockstep builder: the welder's; the holder's (gmf1 holder only)
    world: dict
    welder_package: str = ""  # the device package whose builder builds the welder
    holder_package: str | None = None  # ... and the holder (None: a fixed holder)
    sensor_package: str = ""  # ... and the one whose lead model makes the truth sensors (the layout's sensor)

    def arm_model(self, name: str):
        """The class of the welder's lockstep arm model ``name`` (its package's ``lockstep_models``:
        the Reis's ``fast``), or None when its package registers none of that name."""
        return _model(self.welder_package, name)

    def lead_sensor(self, model: str):
        """The class of the trial's lead sensor of model ``model`` (camera, ideal): the ``lead``
        lockstep model of the layout's ``sensor``'s package (the MVS's LeadSensor, droid.sim.mvs.trial_sensors;
        the tool-tip sensor its instances' ``tool_tip``).  BadInput when it has no such model."""
        cls = _model(self.sensor_package, "lead")
        if model not in cls.models:
            raise BadInput(f"{self.cell.path}: [subunits.{self.layout.sensor}] has no {model} sensor model: "
                           f"package {self.sensor_package!r}'s lead sensor has {', '.join(cls.models)}")
        return cls

    def build_arms(self, sched, geo, arm_model: str, seed: int, fast_params, mark=None):
        """The trial's welder and holder on ``sched``, ready at the start (thesis §6.1.1-6.1.2):
        the welder, the ``tool_robot`` -- ``fast``: its package's model of that name (the Reis's
        FastArm, droid.sim.reis.fast_arm, at ``geo``'s start pose with ``fast_params``); ``full``:
        a FullArm over the arm its builder builds, homed and at the start pose -- then the holder, the ``holder_robot``
        -- its package's holder model (the GMF1's Gmf1Holder) over the subunit its builder builds,
        at ``geo``'s holding pose; None for a
        fixed holder (no holder builder).  Both are the trial cell's subunits, started in that order on
        ``sched`` (droid.sim.lockstep_cell.LockstepCell.add) with the trial's ``seed`` and world;
        ``mark(phase, sched)`` is told the phases ``built``, ``homed`` and ``approached`` (the
        experiments' phase report, droid.experiments.phases; none by default)."""
        from droid.sim.lockstep_cell import build_lockstep_cell

        tool_robot, holder_robot = self.layout.tool_robot, self.layout.holder_robot
        mark = mark or no_mark
        # the trial's cell with nothing started yet: its start order is the welder (homed and at
        # its start), then the holder -- the holder never ticks while the welder homes
        cell = build_lockstep_cell(self.cell, seed, world=self.world, sched=sched, subunits={})
        if arm_model != "full":  # a model its package registers (the Reis's fast: droid.sim.reis.fast_arm)
            arm = self.arm_model(arm_model)(geo.tool, geo.q_tool_start_deg, fast_params)
            arm.name = tool_robot  # the subunit the tracker's fault rule names
            for phase in ("built", "homed", "approached"):  # no homing, no approach: it starts at the start
                mark(phase, sched)
        else:
            welder = cell.add(tool_robot, self.builders[tool_robot])
            arm = FullArm(sched, geo.tool, geo.q_tool_start_deg, welder.arm, mark)
            mark("built", sched)
            arm.prepare()
        if holder_robot not in self.builders:
            return arm, None
        built = cell.add(holder_robot, self.builders[holder_robot])
        holder = _model(self.holder_package, "holder")(sched, built, geo.q_hold_deg)
        holder.prepare()
        return arm, holder


def bundled_cells() -> list[str]:
    return sorted(p.name for p in BUNDLED_CELLS.glob("*.toml") if "layout" not in p.name)


def resolve_cell_path(spec: str, base_dir: str | os.PathLike | None = None) -> Path:
    """A cell file by path (relative to ``base_dir``, default the working directory), or by the
    bare name of a bundled cell (``abb_weld.toml``, ``abb_weld``).  BadInput when there is none."""
    found = find_file(spec, Path(base_dir) if base_dir is not None else Path.cwd(), ".toml")
    if found is None:
        raise BadInput(f"cell file not found: {spec} (bundled cells: {', '.join(bundled_cells())})")
    return found


def _subunit(cell: Cell, layout: Layout, role: str):
    """The subunit of ``cell`` that the layout names ``role`` (tool_robot, holder_robot); BadInput,
    one line naming both files, when the cell has none of that name."""
    name = getattr(layout, role)
    if name not in cell.subunits:
        raise BadInput(f"{cell.path}: its layout {layout.source} names {role} {name!r}, a subunit the cell "
                       f"does not have (its subunits: {', '.join(sorted(cell.subunits))})")
    return cell.subunits[name]


def _whole_builder(cell: Cell, layout: Layout, role: str, what: str, fitting) -> tuple:
    """The lockstep builder of the layout's ``role`` subunit and its package's name: the one
    lockstep_cell.choose_builder picks (by the programs the subunit runs), which must be one of
    ``fitting(cell, sub)`` (builder -> package name) and stand for no program the subunit does not
    run (the trial needs every station of its arm); BadInput, one line naming the file, the
    subunit and what is missing."""
    from droid.sim.lockstep_cell import choose_builder

    sub = _subunit(cell, layout, role)
    where = f"{cell.path}: [subunits.{sub.name}] (the layout's {role})"
    if not sub.is_arm:
        raise BadInput(f"{where} is a {sub.cls} subunit, not an arm: it has no lockstep {what}")
    builders = fitting(cell, sub)
    try:
        build = choose_builder(cell, sub)
    except BadInput:
        build = None
    if build in builders and set(build.programs) <= set(sub.programs):
        getattr(build, "check", lambda c, s: None)(cell, sub)  # what the builder refuses (the ABB: no controller twin), before anything runs
        return build, builders[build]
    runs = ", ".join(sub.programs) or "no programs"
    needs = " or ".join(f"{' + '.join(b.programs)} ({name})" for b, name in builders.items())
    raise BadInput(f"{where} has no lockstep {what}: it runs {runs}; a lockstep {what} needs {needs}")


def resolve_trial_cell(cell: str | os.PathLike | Cell | None = None, arm_model: str = "full",
                       holder: str = "gmf1", layout: Layout | None = None) -> TrialCell:
    """The cell of a trial, read and checked once before anything runs (see the module
    docstring): ``cell`` a cell file's path, a parsed Cell, or None -- the built-in cell
    (:func:`builtin_cell`); its layout, or ``layout`` when given.  BadInput, one line, otherwise."""
    cell = builtin_cell() if cell is None else cell if isinstance(cell, Cell) else load_cell(cell)
    layout = layout_for_cell(cell) if layout is None else layout
    if cell.heartbeat_hz != HEARTBEAT_HZ:
        raise BadInput(f"{cell.path}: heartbeat_hz {cell.heartbeat_hz:g}: the lockstep trial runs at "
                       f"{HEARTBEAT_HZ:g} Hz (its 30 Hz tracking cycle is 2 ticks)")
    welder, package = _whole_builder(cell, layout, "tool_robot", "arm", welder_builders)
    builders, holder_package, world = {layout.tool_robot: welder}, None, {}
    if holder == "gmf1":  # the holder_robot through its own controller: its package's holder model
        builders[layout.holder_robot], holder_package = _whole_builder(cell, layout, "holder_robot", "holder",
                                                                       holder_builders)
        world = _model(holder_package, "holder").trial_world(layout.holder_robot)
    else:
        _subunit(cell, layout, "holder_robot")
    check_bases(layout, cell)
    check_robots(layout, cell)
    sensor = _subunit(cell, layout, "sensor")
    sensors = sensor_packages(cell, sensor)
    if not sensors:
        raise BadInput(f"{cell.path}: [subunits.{sensor.name}] (the layout's sensor) has no trial sensors: no "
                       f"package serving class {sensor.cls!r} registers a lead model (DevicePackage.lockstep_models)")
    tc = TrialCell(cell, layout, builders, world, package, holder_package, sensors[0])
    if arm_model != "full" and tc.arm_model(arm_model) is None:
        raise BadInput(f"{cell.path}: [subunits.{layout.tool_robot}] has no {arm_model} arm model: package "
                       f"{package!r} registers none (its DevicePackage.lockstep_models); use the full model (--arm full)")
    return tc


def builtin_cell() -> Cell:
    """The cell of a trial without a cell file: the built-in cell (droid/cells/sim.toml, whatever
    $DROID_CELL says) with the cell file's default ``stale_ticks`` (LIVENESS_TICKS, the thesis's 3)
    for its 12 -- the arms such a trial always ran: sim.toml's 12 is set against this host's
    real-time stalls, which virtual time has none of, and a fault's order in the Status (a dead
    servo: the servo agent's fault before the watchdog's) follows it."""
    return replace(load_cell(builtin_cell_path()), stale_ticks=LIVENESS_TICKS)


# The ``full`` arm model: every core of the real-time arm subunit (docs/experiments.md, "--arm").
HOME_TIMEOUT_S = 60.0
MOVE_S = 4.0  # the move from home to the start pose
SETTLE_S = 1.0


class FullArm:
    """An arm subunit's cores on a scheduler, with the harness's arm interface.

    The experiments' default arm model (issue 13 item 5): a trial first homes the arm (the Reis's
    servo homing from its seeded power-up pose, thesis §4.1.5.3) and moves it to the start pose
    with a joint command; then the seam-tracking core drives it with cartesian commands through
    the Brain Command record, exactly as droid-seamtrack does.  Every repetition homes, so
    experiment 4 measures repeatability; ~5-10x slower than the ``fast`` model
    (droid.sim.reis.fast_arm; docs/benchmarks.md).

    ``arm``: the lockstep arm its package's builder built on ``sched`` -- a droid.arm.protocol.Arm that
    also shows the world's ``wcp_global`` (a builder declared with ``truth``: the Reis's
    :class:`~droid.sim.reis.cell.LockstepArm`, droid.sim.abb.lockstep.LockstepAbbArm, a lab's own; the
    trial cell's welder, built by TrialCell.build_arms) whose robot model
    is ``model``; ``mark(phase, sched)`` is told the phases ``homed`` and ``approached`` (the
    experiments' phase report, droid.experiments.phases; none by default)."""

    def __init__(self, sched: Scheduler, model, q_start_deg, arm, mark=None) -> None:
        self.sched = sched
        self.model = model
        self.arm = arm
        self.q_start = np.asarray(q_start_deg, float)
        self.mark = mark or no_mark

    def prepare(self) -> None:
        """Home (the Reis searches its switches; the ABB measures absolutely and homes at once),
        then move to the start pose; raises RuntimeFailure if either does not finish."""
        if not self.arm.home(HOME_TIMEOUT_S):
            raise RuntimeFailure(f"full arm model {self.name}: homing did not finish")
        self.mark("homed", self.sched)
        counts = np.rint(self.model.gearing.joints_to_counts(self.q_start)).astype(np.int32)
        cmd = self.arm.command_joint(counts, self.arm.ticks_for(MOVE_S))
        if not self.arm.move_done(cmd, MOVE_S + 5.0):
            raise RuntimeFailure(f"full arm model {self.name}: the move to the start pose did not finish")
        self.sched.run_for(SETTLE_S)
        self.mark("approached", self.sched)

    def command_cart(self, T_global_wcp, ticks: int) -> None:
        self.arm.command_cart(T_global_wcp, ticks)

    def status_pose(self) -> np.ndarray:
        return record_pose(self.arm.read())

    def status_joints(self) -> np.ndarray:
        return self.model.gearing.counts_to_joints(np.asarray(self.arm.read()["encoder_pos"], float))

    @property
    def name(self) -> str:
        """The arm's subunit name (arm1; the layout's tool_robot on a cell)."""
        return self.arm.name

    def status_fault(self) -> int:
        """The Brain Status ``fault`` bits (FAULT_*), as droid-seamtrack reads them."""
        return int(self.arm.read()["fault"])

    def true_wcp(self) -> np.ndarray:
        return self.arm.wcp_global()

    def tick(self) -> None:  # the cores run on the scheduler by themselves
        pass
