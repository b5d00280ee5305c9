"""The Reis subunit in lockstep: every program cycle of the real-time cell, in one process.

The same stations (read -> core.step -> write) as the processes of ``droid-cell up``, on
virtual time (:class:`droid.sim.lockstep.Scheduler`), joined by in-memory databases
(:class:`~droid.brain.db.shmdb.MemoryDatabase`) and in-memory messages (the same bytes)
instead of shared memory and ZeroMQ:

==========================  ========  ==============================================
station                     rate      process it stands for
==========================  ========  ==============================================
ReisPlant                   500 Hz    droid-sim (the robot behind the VME map; 4 substeps of 0.5 ms)
WatchdogStation             50 Hz     droid-watchdog
ServoStation                500 Hz    droid-servo
ServoAgentStation           60 Hz     droid-servo-agent (half a period after the relayed tick)
RemoteStation, AgentStation tick      droid-remote, droid-reis-agent (Brain Command -> controller)
PlannerStation              tick      droid-planner (on the agent's relayed tick)
RemoteStation               tick      droid-remote (the reply: controller Status -> Brain Status, FK)
==========================  ========  ==============================================

Only the transport and the clock are lockstep's own.  One ordering is too: the reply
carries the Status after the planner's cycle of the same tick, where the real-time agent
replies before its relayed tick reaches the planner (so its reply shows the previous plan).

Task programs use :class:`LockstepArm` like BrainArm uses the shared
databases: ``command_joint``, ``command_cart`` (ticks, as BrainArm's), ``command_home``
write the Brain's Command record; ``status`` is the Brain's Status record.  That Brain side
(records, remote, agent, planner, the tick's order) is :class:`droid.sim.arm_chain.ArmChain`,
which the ABB's lockstep arm (droid.sim.abb.lockstep) shares.

:func:`build` is the Reis package's lockstep builder (the registry's ``lockstep`` slot,
droid.sim.lockstep_build): one arm subunit of a cell file, with its ``reis_vme`` world device's
errors (:func:`arm_from_device`); a program the subunit does not run is switched off.
"""
from __future__ import annotations

import numpy as np

from droid.brain.plumbing.wire import LIVENESS_TICKS
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T
from droid.sim.arm_chain import ArmChain
from droid.sim.lockstep import ORDER_DEVICE, ORDER_WORLD, Scheduler
from droid.sim.lockstep_build import LockstepSubunit, builds
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.servo_agent import COMMAND_HZ as AGENT_HZ
from droid.subunits.reis.servo_agent import ServoAgentCore
from droid.subunits.reis.servo_params import ServoParams
from droid.subunits.reis.station import ServoAgentStation, ServoStation, WatchdogStation
from droid.subunits.reis import device as reis_device
from droid.subunits.reis.vme import VmeBus
from droid.subunits.reis.watchdog import WatchdogCore

PLANT_HZ = 500  # plant advances per second; each integrates 1/PLANT_HZ in 0.5 ms substeps.  The
# DACs change only at servo ticks and the encoders are read only there, so stepping the plant
# once per servo tick (just before it) is exact; it saves three quarters of the register traffic.
SERVO_HZ = int(reis_device.SERVO_HZ)  # droid.subunits.reis.device: the one declaration
WATCHDOG_HZ = int(reis_device.WATCHDOG_HZ)
STALE_TICKS = LIVENESS_TICKS  # the cell file's default stale_ticks


class LockstepArm(ArmChain):
    """One Reis arm, all of its programs' stations, on a scheduler (the Brain side: ArmChain)."""

    def __init__(self, sched: Scheduler, name: str = "arm1", robot: str = "reis_v15",
                 base=(0, 0, 0, 0, 0, 0), seed: int = 1, plant_params: ReisPlantParams | None = None,
                 home_offset_deg=None, stale_ticks: int = STALE_TICKS, **plant_kw) -> None:
        model = load_robot(robot).with_base(pose_to_T(*base))
        # servo, servo agent, planner and plant read the same robot file (issue 13)
        pp = plant_params if plant_params is not None else ReisPlantParams(robot=robot)
        if pp.robot != robot:
            raise ValueError(f"arm {name}: the controller's robot file {robot!r} and the plant's {pp.robot!r} differ")
        self.plant = ReisPlant(pp, seed, **plant_kw)
        self.bus = VmeBus.from_buffer(self.plant.regs)
        self._make_chain(sched, name, model, stale_ticks)
        self.restart_servo(home_offset_deg)
        self.watchdog = WatchdogStation(WatchdogCore(), self.bus, self.ctrl_status)
        self.agent = ServoAgentStation(ServoAgentCore(self.stale_ticks, params=self.servo_params),
                                       self.ctrl_command, self.ctrl_status, AGENT_HZ)
        self.alive = {"servo": True, "watchdog": True, "agent": True, "planner": True, "link": True}
        self._relayed = True  # a relayed tick since the servo agent's last cycle
        p = 1e9
        sched.every(PLANT_HZ, self._plant, f"{name}.plant", order=ORDER_WORLD)
        sched.every(SERVO_HZ, self._servo, f"{name}.servo", order=ORDER_DEVICE)
        sched.every(WATCHDOG_HZ, self._watchdog, f"{name}.watchdog", order=ORDER_DEVICE)
        sched.every(AGENT_HZ, self._servo_agent, f"{name}.servo_agent", order=ORDER_DEVICE,
                    phase_ns=int(p / AGENT_HZ / 2))
        self._start_chain()  # planner, agent, remote and the tick (ArmChain._tick)

    @property
    def servo(self) -> ServoCore:
        return self.servo_station.core

    # -- the stations, as their processes run them; only the transport is lockstep's ------
    def _plant(self, t_ns: int) -> None:
        self.plant.advance(1.0 / PLANT_HZ)

    def _servo(self, t_ns: int) -> None:
        if not self.alive["servo"]:
            return
        inbox = self._inbox
        if inbox:  # ZeroMQ PUSH/PULL from the servo agent (a message at 60 Hz: most ticks none)
            for msg in inbox:
                self.servo_station.take(msg)
            inbox.clear()
        report = self.servo_station.cycle()
        if report is not None:  # ZeroMQ PUB/SUB to the servo agent and the watchdog
            self.watchdog.take(report)
            self.agent.take(report, t_ns)

    def _watchdog(self, t_ns: int) -> None:
        if self.alive["watchdog"]:
            self.watchdog.cycle()

    def _servo_agent(self, t_ns: int) -> None:
        # droid-servo-agent cycles on the relayed tick once the planner wrote (real time
        # waits up to a third of a period for it; lockstep's half period is deterministic)
        # and on its own clock when no tick came: ``ticked`` says which
        ticked, self._relayed = self._relayed, False
        if self.alive["agent"]:
            msg = self.agent.cycle(t_ns, ticked=ticked)
            if msg is not None:
                self._inbox.append(msg)

    def _relay_seen(self, relay: int | None) -> None:
        self._relayed |= relay is not None

    def restart_servo(self, home_offset_deg=None) -> None:
        """(Re)start droid-servo with calibrated switch positions (the robot file's plus
        ``home_offset_deg``): the new servo starts unhomed, as a restarted program does."""
        self.home_offset_deg = np.zeros(6) if home_offset_deg is None else np.asarray(home_offset_deg, float)
        self.servo_params = ServoParams.from_robot(self.model, home_offset_deg)
        self.servo_station = ServoStation(ServoCore(self.servo_params), self.bus)
        self._inbox: list[bytes] = []  # servo-agent -> servo messages (ZeroMQ PUSH/PULL)

    # -- the world's side ---------------------------------------------------------------
    def wcp_global(self) -> np.ndarray:
        """The true wrist-centre pose [mm, global frame] (the world's arm-twin interface): the
        true arm (its D-H errors) at its true link angles (after the drives' deflection)."""
        if self.plant.params.dh_error.zero:
            return self.model.fk(self.plant.joint_deg)
        return self.model.base @ self.plant.wcp_true()

    def attach_contact(self, contact) -> None:
        """Let the world push on the tool: ``contact`` (droid.sim.contact.ToolContact, or None to
        take it away) gives the plant its joint torques J^T F at each step."""
        self.plant.contact = contact

    def contact_wrench_N_Nm(self) -> tuple[np.ndarray, np.ndarray]:
        """The environment's wrench on the tool (global frame; force [N], torque [N m] about the
        tool point): the F/T twin's hook (docs/ft.md).  Zero without contact."""
        c = self.plant.contact
        return c.contact_wrench_N_Nm() if c is not None else (np.zeros(3), np.zeros(3))

    def truth(self) -> dict:
        """The world's truth about this arm, as ``droid-sim truth ARM --json`` prints it."""
        from droid.sim.truth import truth_dict

        return truth_dict(self.name, self.plant.time_s, self.plant.joint_deg, self.wcp_global()[:3, 3])


def arms_from_cell(sched: Scheduler, cell, seed: int | None = None) -> dict[str, LockstepArm]:
    """The cell file's Reis arms (its ``reis_vme`` world devices) as lockstep arms on ``sched``.

    Each arm reads its subunit's robot file and base; its plant carries the device table's
    world errors (``home_error_deg``, ``calibration_seed``, ``link_error_mm``,
    ``twist_error_deg``; droid.sim.reis.world) and its contact (``contact_workpiece``), and a device naming a different robot file
    than its subunit is refused, as droid-sim refuses it.  Its agents count the cell's
    ``stale_ticks``, as in real time and as the cell's lockstep builder (:func:`build`) does.
    """
    arms = {}
    world_seed = int(cell.world.get("seed", 0)) if seed is None else seed
    for name, opts in cell.world.get("devices", {}).items():
        if not isinstance(opts, dict) or opts.get("type") != "reis_vme":
            continue
        arm = arm_from_device(sched, cell, name, {k: v for k, v in opts.items() if k != "type"}, world_seed,
                              cell.stale_ticks)
        arms[arm.name] = arm
    return arms


def arm_from_device(sched: Scheduler, cell, name: str, opts: dict, world_seed: int,
                    stale_ticks: int = STALE_TICKS) -> LockstepArm:
    """The Reis arm of world device ``name`` (its ``reis_vme`` table ``opts`` without ``type``) on
    ``sched``: its subunit's robot file, base and calibrated offsets, the table's world errors
    and contact (see :func:`arms_from_cell`); ``stale_ticks`` [heartbeat ticks]."""
    from droid.cli import BadInput
    from droid.sim.reis.world import contact_from_options, device_subunit, world_errors
    from droid.subunits.reis.robot_file import read_offsets

    where, sub = device_subunit(cell, name, opts)
    model = load_robot(sub.robot)
    home_error, dh_error = world_errors(where, model, opts)
    pp = ReisPlantParams(robot=sub.robot, home_error_deg=home_error, dh_error=dh_error)
    try:  # droid-calibrate's offsets, where droid-servo finds them
        offsets = read_offsets(cell, sub.name)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    arm = LockstepArm(sched, sub.name, robot=sub.robot, base=tuple(sub.base), seed=int(opts.get("seed", world_seed)),
                      plant_params=pp, home_offset_deg=offsets, stale_ticks=stale_ticks)
    arm.attach_contact(contact_from_options(where, opts, arm.model.base))
    return arm


def _contacts(ctx, devices: dict) -> None:
    """The cell's ``contact`` world devices on this arm's device (its ``tool_robot``), built by the
    twin's own factory once every twin exists (the workpiece may ride on another arm)."""
    from types import SimpleNamespace

    from droid.sim.contact_device import make_contact

    world = SimpleNamespace(devices=ctx.twins, seed=ctx.seed, cell=ctx.cell)
    for name, opts in ctx.world_devices("contact").items():
        if opts.get("tool_robot") in devices:
            ctx.twins[name] = make_contact(world, name, dict(opts))


#: program -> its switch in LockstepArm.alive
PROGRAM_ALIVE = {"droid-watchdog": "watchdog", "droid-servo": "servo", "droid-servo-agent": "agent",
                 "droid-reis-agent": "link", "droid-planner": "planner"}


@builds("droid-watchdog", "droid-servo", "droid-servo-agent", "droid-reis-agent", "droid-planner",
        truth=True)  # LockstepArm.wcp_global: the plant's true arm
def build(ctx, sub):
    """The lockstep slot of the Reis package (droid.sim.lockstep_build): the subunit's arm, from
    its ``reis_vme`` world device when the cell has one (its world errors), else the controller's
    robot file alone; the cell's ``stale_ticks``; the ``contact`` world devices on its tool (once
    every twin is built).  Stations: the table of the module docstring."""
    from droid.cli import BadInput

    devices = {n: o for n, o in ctx.world_devices("reis_vme").items() if o.get("subunit", n) == sub.name}
    if len(devices) > 1:
        raise BadInput(f"{ctx.where(sub)} has {len(devices)} reis_vme world devices ({', '.join(devices)}): "
                       f"one arm, one twin")
    if devices:
        (device, opts), = devices.items()
        arm = arm_from_device(ctx.sched, ctx.cell, device, opts, ctx.seed, ctx.cell.stale_ticks)
        ctx.twins[device] = arm
    else:
        arm = LockstepArm(ctx.sched, sub.name, robot=sub.robot, base=tuple(sub.base), seed=ctx.seed,
                          stale_ticks=ctx.cell.stale_ticks)
    n = sub.name
    stations = {"droid-watchdog": [f"{n}.watchdog"], "droid-servo": [f"{n}.servo"],
                "droid-servo-agent": [f"{n}.servo_agent"], "droid-reis-agent": [f"{n}.tick"],
                "droid-planner": [f"{n}.tick"]}
    for prog, alive in PROGRAM_ALIVE.items():  # a program the subunit does not run does not run
        arm.alive[alive] = prog in sub.programs
    ctx.after(lambda: _contacts(ctx, devices))
    return LockstepSubunit(n, sub.cls, arm.brain_status, arm.brain_command,
                           {p: t for p, t in stations.items() if p in sub.programs}, arm, arm)
