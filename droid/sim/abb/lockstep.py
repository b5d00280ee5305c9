"""The ABB subunit on EGM in lockstep: its programs' stations and its controller twin, one process.

The processes of an ABB subunit in a real-time cell (docs/abb.md; issue 26, thesis §7.3), as
stations on virtual time (:class:`droid.sim.lockstep.Scheduler`), joined by in-memory databases
and by the very EGM datagrams the sockets would carry (protobuf bytes, handed over in memory):

==========================  ==========  ==============================================
station                     rate        process it stands for
==========================  ==========  ==============================================
EgmController               world rate  droid-sim's ``abb_egm`` device: the IRC5 running DroidEGM.mod;
                            (1 kHz)     an ``EgmRobot`` every 4 ms of its clock, ``EgmSensor`` targets in
EgmStation.take             same step   droid-egm: each datagram answered at once, the reply handed
                                        back to the controller as bytes
RemoteStation, AgentStation tick        droid-remote, droid-reis-agent (Brain Command -> controller)
PlannerStation              tick        droid-planner (on the agent's relayed tick, §4.1.7)
EgmStation.cycle            tick        droid-egm's heartbeat cycle, on the relayed tick after the
                                        planner (its TickPacer's wait, without the wait)
RemoteStation               tick        droid-remote (the reply: controller Status -> Brain Status, FK)
==========================  ==========  ==============================================

Only the transport and the clock are lockstep's own (the pattern of
:class:`droid.sim.reis.cell.LockstepArm`, whose Brain side, :class:`droid.sim.arm_chain.ArmChain`,
this arm shares).  Built from a cell file (:class:`LockstepAbbArm`): the subunit's robot file
and base, its cell's ``stale_ticks`` and heartbeat, and the ``[world.devices.*]`` table of type
``abb_egm`` that serves the subunit (``start_deg``, ``comm_timeout_s``, ... through
:func:`droid.sim.abb.controller.egm_twin`, the device factory's own reading), stepped at the
world's ``rate_hz``.  Nothing is random: a run is the same every time.
"""
from __future__ import annotations

import numpy as np

from droid.brain.db.shmdb import MemoryDatabase
from droid.cli import BadInput
from droid.kinematics.transforms import pose_to_T
from droid.sim.arm_chain import ArmChain
from droid.sim.lockstep import ORDER_WORLD, Scheduler
from droid.sim.lockstep_build import LockstepSubunit, builds

# The controller twin and droid-egm's core and station (with the EGM protobuf schema) are
# imported by LockstepAbbArm when it is built: choosing a lockstep builder imports every arm
# package's builder module (droid.sim.lockstep_cell.class_builders), a Reis trial too (issue 44).

TWIN_TYPE = "abb_egm"
#: The world's step rate when the cell's [world] names none [Hz] (droid-sim's default)
DEFAULT_WORLD_HZ = 1000.0
#: The controller's source address in droid-egm's eyes: lockstep binds no socket (port 0: none)
CONTROLLER_ADDRESS = ("127.0.0.1", 0)


def egm_device(cell, subunit: str) -> tuple[str, dict]:
    """The ``[world.devices.NAME]`` table of type ``abb_egm`` serving ``subunit``: ``(NAME, options
    without type)``.  BadInput (one line naming the file) when the cell has none."""
    for name, opts in cell.world.get("devices", {}).items():
        if isinstance(opts, dict) and opts.get("type") == TWIN_TYPE and opts.get("subunit", name) == subunit:
            return name, {k: v for k, v in opts.items() if k != "type"}
    raise BadInput(f"{cell.path}: [subunits.{subunit}] has no controller twin: no [world.devices.*] "
                   f"of type {TWIN_TYPE} serves it (the ABB's lockstep steps that twin)")


class LockstepAbbArm(ArmChain):
    """One ABB arm on EGM, every station of its subunit and its controller twin, on ``sched``.

    ``cell``: the cell file (droid.brain.cell.cellfile.Cell); ``subunit``: its ABB arm.  The task
    interface is :class:`~droid.sim.arm_chain.ArmChain`'s (``status``, ``command_*``, ``home``,
    ``move_done``, ...); :meth:`wcp_global` and :meth:`truth` are the world's.  ``alive``:
    ``egm``/``planner``/``link`` false stops that program (fault-injection tests)."""

    def __init__(self, sched: Scheduler, cell, subunit: str = "abb") -> None:
        from droid.sim.abb.controller import EgmController, egm_twin
        from droid.subunits.abb.egm_core import EgmCore
        from droid.subunits.abb.egm_layout import EGM_STATUS_LAYOUT
        from droid.subunits.abb.egm_prog import EgmStation

        sub = cell.subunit(subunit)
        if sched.heartbeat_hz != cell.heartbeat_hz:
            raise BadInput(f"{cell.path}: heartbeat_hz {cell.heartbeat_hz:g} differs from the lockstep "
                           f"scheduler's {sched.heartbeat_hz:g} Hz")
        device, options = egm_device(cell, sub.name)
        _, _, controller = egm_twin(cell, device, options)
        self.controller: EgmController = controller
        self.device = device
        self._make_chain(sched, sub.name, controller.model.with_base(pose_to_T(*sub.base)), cell.stale_ticks)
        self.egm_db = MemoryDatabase(f"{sub.name}.egm", EGM_STATUS_LAYOUT)
        core = EgmCore(controller.model, cell.stale_ticks, cell.heartbeat_hz)
        self.egm = EgmStation(core, self.ctrl_command, self.ctrl_status, self.egm_db)
        self.alive = {"egm": True, "planner": True, "link": True}
        self.world_hz = float(cell.world.get("rate_hz", DEFAULT_WORLD_HZ))
        self.t0_ns = sched.t_ns  # the controller's power-up: its clock starts here
        sched.every(self.world_hz, self._world, f"{sub.name}.world", order=ORDER_WORLD)
        self._start_chain()  # planner, agent, remote and the tick (ArmChain._tick)

    # -- the stations, as their processes run them; only the transport is lockstep's ------
    def _world(self, t_ns: int) -> None:
        """One world step: the controller runs to now and sends what is due (UDP in real time);
        droid-egm answers each datagram at once and the reply reaches the controller before its
        next step (the device reads its socket at the start of each step)."""
        t_s = (t_ns - self.t0_ns) / 1e9
        c = self.controller
        for data in c.advance(t_s):
            if not self.alive["egm"]:
                continue  # nobody listens: the datagram is lost
            reply = self.egm.take(data, CONTROLLER_ADDRESS, t_ns)
            if reply is not None:
                c.receive(reply[0], t_s)

    def _after_planner(self, relay: int | None, t_ns: int) -> None:
        # droid-egm cycles on the relayed tick once the planner wrote, on its own clock when no
        # tick came (TickPacer): once a heartbeat period either way
        if self.alive["egm"]:
            self.egm.cycle(t_ns)

    # -- the world's side ---------------------------------------------------------------
    @property
    def counters(self):
        """droid-egm's link counters (egm_core.Counters: accepted, lost, ... replies)."""
        return self.egm.core.counters

    def wcp_global(self) -> np.ndarray:
        """The true pose of the model's frame (4x4, mm, global): for this arm the flange (tool0,
        docs/abb.md) at the links' true angles (after the reducers' deflection)."""
        return self.model.fk(self.controller.q_deg)

    def truth(self) -> dict:
        """The world's truth about this arm, as ``droid-sim truth ARM --json`` prints it."""
        from droid.sim.truth import truth_dict

        return truth_dict(self.name, self.controller.t_s, self.controller.q_deg, self.wcp_global()[:3, 3])


@builds("droid-egm", "droid-reis-agent", "droid-planner", check=lambda cell, sub: egm_device(cell, sub.name),
        truth=True)  # LockstepAbbArm.wcp_global: the controller twin's arm
def build(ctx, sub) -> LockstepSubunit:
    """The lockstep slot of the ABB package (droid.sim.lockstep_build): :class:`LockstepAbbArm` of
    the subunit and its ``abb_egm`` world device (BadInput naming the file when there is none)."""
    arm = LockstepAbbArm(ctx.sched, ctx.cell, sub.name)
    ctx.twins[arm.device] = arm
    n = sub.name
    stations = {"droid-egm": [f"{n}.world", f"{n}.tick"], "droid-reis-agent": [f"{n}.tick"],
                "droid-planner": [f"{n}.tick"]}
    for prog, alive in (("droid-egm", "egm"), ("droid-planner", "planner"), ("droid-reis-agent", "link")):
        arm.alive[alive] = prog in sub.programs
    return LockstepSubunit(n, sub.cls, arm.brain_status, arm.brain_command,
                           {p: t for p, t in stations.items() if p in sub.programs}, arm, arm)
