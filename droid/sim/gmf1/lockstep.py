"""Lockstep GMF1: the Fanuc twin and the GMF1 programs' cores in one process on virtual time (docs/design.md §2).

Stepped by :class:`droid.sim.lockstep.Scheduler`:

* ``world`` (ORDER_WORLD, ``world_hz``): the ``karel_s400`` device — KAREL
  controller at 9600 baud on an in-memory serial pair, encoder cards in
  bytearrays;
* ``encoder`` (ORDER_DEVICE, 120 Hz): :class:`~droid.subunits.gmf1.station.EncoderStation`
  reading the cards through the same :class:`~droid.subunits.gmf1.quad04.Quad04Bank`;
* on every heartbeat tick: the agent's copy of the Brain Command record into
  the controller's Command record (:class:`~droid.subunits.agent.CommandCopier`),
  then :class:`~droid.subunits.gmf1.station.SerialStation` (the relayed tick).

Exactly the code of the real-time programs runs between the records, the port
and the cards; only the transports differ.  The package's lockstep builder (:func:`build`,
droid.sim.lockstep_build) adds droid-remote (:class:`Gmf1Remote`: the Brain Status) and reads
the cell's ``karel_s400`` world device.  Commands are written into the
Brain Command record as droid-move / droid-home write them.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from droid.brain.cell.cellfile import Cell, load_cell
from droid.brain.db import arm_command
from droid.brain.db.layouts import (ARM_COMMAND_LAYOUT, ARM_STATUS_LAYOUT, CTRL_COMMAND_LAYOUT, CTRL_STATUS_LAYOUT,
                                 NORMAL_MODE)
from droid.brain.db.databases import safe_start
from droid.brain.runtime.remote import RemoteStation, StatusTranslator
from droid.brain.db.shmdb import MemoryDatabase
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T
from droid.sim.arm_chain import ArmTasks
from droid.sim.gmf1.cards import Quad04Twin
from droid.sim.gmf1.controller import KarelController, KarelParams
from droid.sim.serial_cable import MemorySerialPair
from droid.sim.gmf1.karel import DEFAULT_START_DEG, KarelDevice
from droid.sim.lockstep import ORDER_DEVICE, ORDER_HEARTBEAT, ORDER_WORLD, Scheduler
from droid.sim.lockstep_build import LockstepSubunit, builds
from droid.subunits.agent import CommandCopier
from droid.subunits.gmf1.config import gmf1_config
from droid.subunits.gmf1.encoder_core import EncoderCore
from droid.subunits.gmf1.port import PortLink
from droid.subunits.gmf1.quad04 import Quad04Bank, Quad04Card
from droid.subunits.gmf1.quad04_map import MAP_SIZE
from droid.subunits.gmf1.serial_core import SerialCore, SerialParams
from droid.subunits.gmf1.station import EncoderStation, SerialStation


class Gmf1Lockstep:
    """The GMF1 subunit and its Fanuc twin on virtual time; see the module docstring."""

    def __init__(self, cell: Cell | None = None, subunit: str = "gmf1", *, world_hz: float = 1000.0,
                 seed: int = 1, start_deg=DEFAULT_START_DEG, params: KarelParams | None = None,
                 sched: Scheduler | None = None, robot: str | None = None, base_T=None,
                 prefix: str = "") -> None:
        """``sched``: put the subunit on this scheduler (a trial's) instead of its own; ``robot``
        and ``base_T`` (4x4, mm): the robot file and base pose instead of the cell's subunit's;
        ``prefix``: before its task names (``"gmf1."``: two GMF1s on one scheduler)."""
        self.cell = cell if cell is not None else load_cell(None)
        self.sub = self.cell.subunit(subunit)
        cfg = gmf1_config(self.cell, self.sub)
        self.cfg = cfg
        model_base = load_robot(robot or self.sub.robot)
        self.model = model_base.with_base(pose_to_T(*self.sub.base) if base_T is None else np.asarray(base_T, float))
        if sched is not None and sched.heartbeat_hz != self.cell.heartbeat_hz:
            raise ValueError(f"gmf1 lockstep: the scheduler's heartbeat {sched.heartbeat_hz:g} Hz is not the "
                             f"cell's {self.cell.heartbeat_hz:g} Hz")
        self.sched = sched if sched is not None else Scheduler(self.cell.heartbeat_hz)
        self.world_hz = float(world_hz)
        # the world: controller + serial pair + cards
        self.pair = MemorySerialPair()
        self.card_bufs = [bytearray(MAP_SIZE), bytearray(MAP_SIZE)]
        twin = Quad04Twin(self.card_bufs, np.random.default_rng(seed))
        controller = KarelController(model_base, params or KarelParams(baud=cfg.baud), np.asarray(start_deg, float))
        twin.update(model_base.gearing.joints_to_counts(controller.q_motor_deg))
        self.device = KarelDevice(self.sub.name, controller, twin, self.pair.device, self.model)
        self.controller = controller
        # the databases
        self.brain_command = MemoryDatabase("brain.command", ARM_COMMAND_LAYOUT)
        self.ctrl_command = MemoryDatabase("ctrl_command", CTRL_COMMAND_LAYOUT)
        self.ctrl_status = MemoryDatabase("ctrl_status", CTRL_STATUS_LAYOUT)
        for db in (self.brain_command, self.ctrl_command):
            safe_start(db)
        self.copier = CommandCopier(self.ctrl_command)
        # the programs
        self.bank = Quad04Bank([Quad04Card(b, f"lockstep card {i}") for i, b in enumerate(self.card_bufs)])
        self.serial_core = SerialCore(self.model, SerialParams(
            period_s=1.0 / self.cell.heartbeat_hz, baud=cfg.baud, reply_timeout_s=cfg.reply_timeout_s,
            done_margin_s=cfg.done_margin_s))
        self.link = PortLink(self.pair.open_host)
        self.serial = SerialStation(self.serial_core, self.link, self.ctrl_command, self.ctrl_status)
        self.encoder_core = EncoderCore(self.model, cfg.encoder_hz)
        self.encoder = EncoderStation(self.encoder_core, self.ctrl_status)
        self.encoder_running = True
        self.serial_running = True
        self._dt = 1.0 / self.world_hz
        self.tasks = {k: prefix + k for k in ("world", "encoder", "agent", "serial")}
        self.sched.every(self.world_hz, self._world, self.tasks["world"], order=ORDER_WORLD)
        self.sched.every(cfg.encoder_hz, self._encoder, self.tasks["encoder"], order=ORDER_DEVICE)
        self.sched.on_tick(self._agent, self.tasks["agent"], order=ORDER_HEARTBEAT)
        self.sched.on_tick(self._serial, self.tasks["serial"], order=ORDER_HEARTBEAT + 1)

    # -- tasks -----------------------------------------------------------------------
    def _world(self, t_ns: int) -> None:
        self.device.advance(self._dt)

    def _encoder(self, t_ns: int) -> None:
        if self.encoder_running:
            self.encoder.cycle(self.bank, t_ns)

    def _agent(self, tick: int) -> None:
        self.copier(self.brain_command.raw_bytes(), tick)
        with self.brain_command.locked() as c:  # the remote's acknowledgement of 'sent'
            c["sent"] = 0

    def _serial(self, tick: int) -> None:
        if self.serial_running:
            self.serial.cycle(tick)

    # -- the Brain side (what droid-move / droid-home write: droid.brain.db.arm_command) ----------
    def command_cart(self, T, ticks: int) -> int:
        """A cartesian move of the WCP to ``T`` (4x4, global frame, mm) in ``ticks`` heartbeat ticks."""
        return arm_command.cart(self.brain_command, T, ticks)

    def command_joint(self, counts, ticks: int) -> int:
        """A joint move: encoder counts wrt home, in ``ticks`` heartbeat ticks."""
        return arm_command.joint(self.brain_command, counts, ticks)

    def command_home(self) -> int:
        return arm_command.home(self.brain_command)

    def ticks_for(self, seconds: float) -> int:
        """``seconds`` [s] as heartbeat ticks of the cell."""
        return arm_command.ticks_for(seconds, self.cell.heartbeat_hz)

    # -- running ------------------------------------------------------------------------
    def status(self):
        return self.ctrl_status.read()

    def done(self, cmd_id: int) -> bool:
        s = self.ctrl_status.read()
        return int(s["cmd_id"]) == cmd_id and int(s["busy"]) == 0

    def run_ticks(self, n: int) -> None:
        self.sched.run_ticks(n)

    def run_until(self, pred, timeout_s: float) -> bool:
        """Advance tick by tick until ``pred()`` holds (True) or ``timeout_s`` virtual seconds pass (False)."""
        end = self.sched.t_ns + int(timeout_s * 1e9)
        while self.sched.t_ns < end:
            self.sched.run_ticks(1)
            if pred():
                return True
        return False

    def home(self, timeout_s: float = 30.0) -> bool:
        """droid-home: command HOME and run until homed and idle (``timeout_s`` [s] at most), then
        NORMAL; whether it homed (as :meth:`droid.sim.arm_chain.ArmTasks.home`; the command's id is
        :attr:`home_id`)."""
        cmd_id = self.home_id = self.command_home()
        ok = self.run_until(lambda: self.done(cmd_id) and int(self.ctrl_status.read()["homed"]) == 1, timeout_s)
        if ok:
            with self.brain_command.locked() as c:
                c["cmd_mode"] = NORMAL_MODE
        return ok

    @property
    def t_s(self) -> float:
        return self.sched.t_s

    def true_pose_global(self) -> np.ndarray:
        """The twin's true wrist-centre pose (4x4, mm, global frame)."""
        return self.device.wcp_global()


class Gmf1Remote:
    """droid-remote of a lockstep GMF1 (thesis §3.2, §4.2.3): on each tick, before the agent's copy,
    the silence rule and the command sent; after the serial program, the controller's Status
    into the Brain Status with the WCP by forward kinematics (§4.1.8)."""

    def __init__(self, ls: Gmf1Lockstep, sub, stale_ticks: int, prefix: str) -> None:
        self.ls = ls
        self.status = MemoryDatabase(f"{sub.name}.status", ARM_STATUS_LAYOUT)
        self.remote = RemoteStation(self.status, ls.brain_command, StatusTranslator.for_subunit(sub),
                                    stale_ticks, ls.sched.heartbeat_hz)
        ls.sched.on_tick(self._send, f"{prefix}remote", order=ORDER_HEARTBEAT - 1)
        ls.sched.on_tick(self._reply, f"{prefix}remote.reply", order=ORDER_HEARTBEAT + 2)

    def _send(self, tick: int) -> None:
        t_ns = self.ls.sched.t_ns
        self.remote.on_poll(t_ns)
        self.remote.on_tick(tick, t_ns)
        self.remote.command_payload()

    def _reply(self, tick: int) -> None:
        self.remote.on_reply(tick, self.ls.ctrl_status.raw_bytes(), self.ls.sched.t_ns)


@builds("droid-gmf1-agent", "droid-gmf1-serial", "droid-gmf1-encoder")
def build(ctx, sub) -> LockstepSubunit:
    """The lockstep slot of the GMF1 package (droid.sim.lockstep_build): :class:`Gmf1Lockstep` on
    the context's scheduler with its ``karel_s400`` world device's start pose, controller
    parameters and seed (the defaults without one), stepped at the world's rate, and its
    droid-remote (:class:`Gmf1Remote`)."""
    from droid.sim.gmf1.karel import karel_params, start_joints

    devices = {n: o for n, o in ctx.world_devices("karel_s400").items() if o.get("subunit", n) == sub.name}
    device, opts = next(iter(devices.items()), (None, {}))
    model = load_robot(sub.robot)
    where = f"{ctx.cell.path}: [world.devices.{device}]"
    start = start_joints(opts, model, model.with_base(pose_to_T(*sub.base)), where)
    params = karel_params(opts, where, model) if device is not None else None
    if params is not None:
        params = dataclasses.replace(params, baud=gmf1_config(ctx.cell, sub).baud)
    prefix = f"{sub.name}."
    ls = Gmf1Lockstep(ctx.cell, sub.name, world_hz=ctx.world_hz, seed=int(opts.get("seed", ctx.seed)),
                      start_deg=start, params=params, sched=ctx.sched, prefix=prefix)
    ls.remote = Gmf1Remote(ls, sub, ctx.cell.stale_ticks, prefix)
    if device is not None:
        ctx.twins[device] = ls.device
    stations = {"droid-gmf1-agent": [ls.tasks["agent"], f"{prefix}remote", f"{prefix}remote.reply"],
                "droid-gmf1-serial": [ls.tasks["serial"]], "droid-gmf1-encoder": [ls.tasks["encoder"]]}
    ls.encoder_running = "droid-gmf1-encoder" in sub.programs
    ls.serial_running = "droid-gmf1-serial" in sub.programs
    arm = ArmTasks.over(ctx.sched, ls.remote.status, ls.brain_command, sub.name)
    return LockstepSubunit(sub.name, sub.cls, ls.remote.status, ls.brain_command,
                           {p: t for p, t in stations.items() if p in sub.programs}, arm, ls)
