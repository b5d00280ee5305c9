"""The part of an arm6r subunit every lockstep arm shares: Brain records -> remote -> agent -> planner.

An arm of class ``arm6r`` that runs ``droid-reis-agent`` and ``droid-planner`` (the Reis, and
the ABB on EGM: docs/abb.md) has the same Brain side whatever closes its joint loops:

==========================  ========  ==============================================
station                     rate      process it stands for
==========================  ========  ==============================================
RemoteStation, AgentStation tick      droid-remote, droid-reis-agent (Brain Command -> controller)
PlannerStation              tick      droid-planner (on the agent's relayed tick, §4.1.7)
(the servo side's hook)     tick      the subclass's program that cycles on the relayed tick
RemoteStation               tick      droid-remote (the reply: controller Status -> Brain Status, FK, §4.1.8)
==========================  ========  ==============================================

:class:`ArmTasks` is that task side alone, over any arm's Brain records (the GMF1's lockstep
builder gives it to task programs).  :class:`ArmChain` makes the four records (the Brain's Status and Command, the controller's
Status and Command: :class:`~droid.brain.db.shmdb.MemoryDatabase`), those stations and the tick's
order, and gives a task program what ``BrainArm`` gives it on shared memory: ``status``,
``command_home``/``command_joint``/``command_cart`` (heartbeat ticks), ``ticks_for``,
``set_normal``, ``run_until``, ``home``, ``move_done``.  The subclass adds the servo side
(:class:`droid.sim.reis.cell.LockstepArm`: servo, servo agent, watchdog, the plant;
:class:`droid.sim.abb.lockstep.LockstepAbbArm`: droid-egm and the controller twin) and
``wcp_global`` (the world's truth about the arm).
"""
from __future__ import annotations

import numpy as np

from droid.arm.planner import PlannerCore, PlannerStation
from droid.brain.db import arm_command
from droid.brain.cell.classes import ARM6R
from droid.brain.db.layouts import (ARM_COMMAND_LAYOUT, ARM_STATUS_LAYOUT, CTRL_COMMAND_LAYOUT,
                                 CTRL_STATUS_LAYOUT)
from droid.brain.db.databases import safe_start
from droid.brain.runtime.remote import RemoteStation, StatusTranslator
from droid.brain.db.shmdb import MemoryDatabase
from droid.sim.lockstep import ORDER_HEARTBEAT, Scheduler
from droid.subunits.agent import AgentStation


class ArmTasks:
    """What a task program sees of a lockstep arm: its Brain records on a scheduler, driven as
    ``BrainArm`` drives them on shared memory (droid.brain.db.arm_command) -- the neutral arm's
    :class:`droid.arm.protocol.Arm`, its waits on virtual time.  Needs ``sched``, ``name``,
    ``brain_status`` and ``brain_command``; :class:`ArmChain` has them, and :meth:`over` makes one
    for any arm's Brain records (the GMF1's)."""

    @classmethod
    def over(cls, sched: Scheduler, brain_status, brain_command, name: str = "") -> "ArmTasks":
        """The task interface of arm ``name`` whose Brain records are ``brain_status``/``brain_command``."""
        arm = cls()
        arm.sched, arm.brain_status, arm.brain_command, arm.name = sched, brain_status, brain_command, name
        return arm

    @property
    def status(self):
        return self.brain_status.read()

    def read(self):
        """The newest Brain Status record (:class:`droid.arm.protocol.Arm`; as ``BrainArm.read``)."""
        return self.brain_status.read()

    def command_home(self) -> int:
        return arm_command.home(self.brain_command)

    def command_joint(self, counts, ticks: int) -> int:
        """A joint move to ``counts`` [encoder counts wrt home] in ``ticks`` heartbeat ticks."""
        return arm_command.joint(self.brain_command, counts, ticks)

    def command_cart(self, T, ticks: int) -> int:
        """A cartesian move of the model's pose to ``T`` (4x4, global frame, mm) in ``ticks`` heartbeat ticks."""
        return arm_command.cart(self.brain_command, T, ticks)

    def ticks_for(self, seconds: float) -> int:
        """``seconds`` [s] as heartbeat ticks of this arm's scheduler."""
        return arm_command.ticks_for(seconds, self.sched.heartbeat_hz)

    def set_normal(self) -> None:
        arm_command.set_normal(self.brain_command)

    def run_until(self, pred, max_s: float, step_s: float = 0.05) -> bool:
        """Advance virtual time until ``pred()`` or ``max_s`` simulated seconds."""
        t_end = self.sched.t_ns + int(max_s * 1e9)
        while self.sched.t_ns < t_end:
            if pred():
                return True
            self.sched.run_for(step_s)
        return bool(pred())

    def home(self, timeout_s: float = 60.0) -> bool:
        """droid-home: HOME, run until homed and idle (``timeout_s`` [s] at most), then NORMAL."""
        cmd_id = self.command_home()
        ok = self.run_until(lambda: int(self.status["cmd_id"]) == cmd_id and int(self.status["homed"])
                            and int(self.status["busy"]) == 0, timeout_s)
        if ok:
            self.set_normal()
        return ok

    def move_done(self, cmd_id: int, timeout_s: float) -> bool:
        """Run until the Status acknowledges ``cmd_id`` and is idle (``timeout_s`` [s] at most)."""
        return self.run_until(lambda: int(self.status["cmd_id"]) == cmd_id and int(self.status["busy"]) == 0,
                              timeout_s)


class ArmChain(ArmTasks):
    """Records, remote, agent and planner of one arm on ``sched``; see the module docstring.

    ``model``: the arm's robot model with its base (mm); ``stale_ticks``: the cell's link
    silence [heartbeat ticks].  Call :meth:`_start_chain` from the subclass's ``__init__`` once
    its own stations exist; it registers the tick (order :data:`ORDER_HEARTBEAT`)."""

    def _make_chain(self, sched: Scheduler, name: str, model, stale_ticks: int) -> None:
        self.sched = sched
        self.name = name
        self.model = model
        self.stale_ticks = int(stale_ticks)
        self.brain_status = MemoryDatabase(f"{name}.status", ARM_STATUS_LAYOUT)
        self.brain_command = MemoryDatabase(f"{name}.command", ARM_COMMAND_LAYOUT)
        self.ctrl_status = MemoryDatabase(f"{name}.ctrl_status", CTRL_STATUS_LAYOUT)
        self.ctrl_command = MemoryDatabase(f"{name}.ctrl_command", CTRL_COMMAND_LAYOUT)
        for db in (self.brain_command, self.ctrl_command):
            safe_start(db)

    def _start_chain(self) -> None:
        sched, name = self.sched, self.name
        self.planner = PlannerStation(PlannerCore(self.model), self.ctrl_command, self.ctrl_status)
        period_ns = int(round(1e9 / sched.heartbeat_hz))
        self.link_agent = AgentStation(self.ctrl_status, self.ctrl_command, period_ns, self.stale_ticks)
        self.remote = RemoteStation(self.brain_status, self.brain_command,
                                    StatusTranslator(name, ARM6R, self.wcp_from_counts), self.stale_ticks,
                                    sched.heartbeat_hz)
        sched.on_tick(self._tick, f"{name}.tick", order=ORDER_HEARTBEAT)

    # -- the heartbeat tick, as the processes run it; only the transport is lockstep's -------
    def _tick(self, tick: int) -> None:
        t_ns = self.sched.t_ns
        self.remote.on_poll(t_ns)  # the heartbeat-silence rule, on virtual time
        self.remote.on_tick(tick, t_ns)
        if self.alive["link"]:  # the remote sends the Brain's command; the agent copies it in
            self.link_agent.on_command(self.remote.command_payload(), tick, t_ns)
            relay = tick
        else:  # the agent's own timer: the link dies after stale_ticks; then local ticks
            relay = self.link_agent.on_timer(t_ns)
        self._relay_seen(relay)
        if self.alive["planner"] and relay is not None:
            self.planner.cycle(relay)
        self._after_planner(relay, t_ns)
        if self.alive["link"]:  # the reply: controller Status -> Brain Status, with FK (§4.1.8)
            self.remote.on_reply(tick, self.ctrl_status.raw_bytes(), t_ns)

    def _relay_seen(self, relay: int | None) -> None:
        """Hook: the agent relayed ``relay`` (None: no tick this period)."""

    def _after_planner(self, relay: int | None, t_ns: int) -> None:
        """Hook: a program that cycles on the relayed tick once the planner has written."""

    # -- what a task program sees --------------------------------------------
    def wcp_from_counts(self, counts) -> np.ndarray:
        """The model's pose (4x4, mm, global) at encoder ``counts`` (the remote's FK, §4.1.8)."""
        return self.model.fk(self.model.gearing.counts_to_joints(np.asarray(counts, float)))
