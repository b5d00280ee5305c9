"""The Reis subunit in lockstep: every program core of the real-time cell, in one process.

The same cores as the processes of ``droid-cell up``, on virtual time
(:class:`droid.sim.lockstep.Scheduler`), joined by in-memory databases
(:class:`~droid.brain.shmdb.MemoryDatabase`) and in-memory messages instead of
shared memory and ZeroMQ:

====================  ========  ============================================
core                  rate      process it stands for
====================  ========  ============================================
ReisPlant             500 Hz    droid-sim (the robot behind the VME map; 4 substeps of 0.5 ms)
WatchdogCore          50 Hz     droid-watchdog
ServoCore             500 Hz    droid-servo
ServoAgentCore        60 Hz     droid-servo-agent (own timer, half a period out of phase)
(command copy)        tick      droid-remote + droid-reis-agent (Brain Command -> controller)
PlannerCore           tick      droid-planner
StatusTranslator      tick      droid-remote (controller Status -> Brain Status, FK)
====================  ========  ============================================

Task programs use :class:`LockstepArm` like BrainArm uses the shared
databases: ``command_joint``, ``command_cart``, ``command_home`` write the
Brain's Command record; ``status`` is the Brain's Status record.
"""
from __future__ import annotations

import numpy as np

from droid.brain.layouts import (ARM_COMMAND_LAYOUT, ARM_STATUS_LAYOUT, CARTSPACE, CTRL_COMMAND_LAYOUT,
                                 CTRL_STATUS_LAYOUT, HOME_MODE, JOG_MODE, JSPACE, NORMAL_MODE)
from droid.brain.shmdb import MemoryDatabase
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T
from droid.sim.lockstep import ORDER_DEVICE, ORDER_HEARTBEAT, ORDER_WORLD, Scheduler
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.subunits.agent import COMMAND_MAP
from droid.subunits.reis import servo_wire as sw
from droid.subunits.reis.planner import PlannerCore
from droid.subunits.reis.planner import apply as apply_plan
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.servo_agent import MY_FAULTS, ServoAgentCore
from droid.subunits.reis.servo_params import ServoParams
from droid.subunits.reis.vme import VmeBus
from droid.subunits.reis.watchdog import WatchdogCore

PLANT_HZ = 500  # plant advances per second; each integrates 1/PLANT_HZ in 0.5 ms substeps.  The
# DACs change only at servo ticks and the encoders are read only there, so stepping the plant
# once per servo tick (just before it) is exact; it saves three quarters of the register traffic.
SERVO_HZ = 500
WATCHDOG_HZ = 50
AGENT_HZ = 60


class LockstepArm:
    """One Reis arm, all of its programs' cores, on a scheduler."""

    def __init__(self, sched: Scheduler, name: str = "arm1", robot: str = "reis_v15",
                 base=(0, 0, 0, 0, 0, 0), seed: int = 1, plant_params: ReisPlantParams | None = None,
                 home_offset_deg=None, **plant_kw) -> None:
        self.sched = sched
        self.name = name
        self.model = load_robot(robot).with_base(pose_to_T(*base))
        # servo, servo agent, planner and plant read the same robot file (issue 13)
        pp = plant_params if plant_params is not None else ReisPlantParams(robot=robot)
        if pp.robot != robot:
            raise ValueError(f"arm {name}: the controller's robot file {robot!r} and the plant's {pp.robot!r} differ")
        self.plant = ReisPlant(pp, seed, **plant_kw)
        self.bus = VmeBus.from_buffer(self.plant.regs)
        self.home_offset_deg = np.zeros(6) if home_offset_deg is None else np.asarray(home_offset_deg, float)
        self.servo_params = ServoParams.from_robot(robot, home_offset_deg)
        self.servo = ServoCore(self.servo_params)
        self.watchdog = WatchdogCore()
        self.agent = ServoAgentCore(params=self.servo_params)
        self.planner = PlannerCore(self.model)
        self.brain_status = MemoryDatabase(f"{name}.status", ARM_STATUS_LAYOUT)
        self.brain_command = MemoryDatabase(f"{name}.command", ARM_COMMAND_LAYOUT)
        self.ctrl_status = MemoryDatabase(f"{name}.ctrl_status", CTRL_STATUS_LAYOUT)
        self.ctrl_command = MemoryDatabase(f"{name}.ctrl_command", CTRL_COMMAND_LAYOUT)
        for db in (self.brain_command, self.ctrl_command):
            db.update(cmd_mode=JOG_MODE, coord=JSPACE)
        self._inbox: list[bytes] = []  # servo-agent -> servo messages (ZeroMQ PUSH/PULL)
        self._report: bytes | None = None  # servo -> agent/watchdog (ZeroMQ PUB/SUB)
        self._report_t = 0
        self.alive = {"servo": True, "watchdog": True, "agent": True, "planner": True, "link": True}
        p = 1e9
        sched.every(PLANT_HZ, self._plant, f"{name}.plant", order=ORDER_WORLD)
        sched.every(SERVO_HZ, self._servo, f"{name}.servo", order=ORDER_DEVICE)
        sched.every(WATCHDOG_HZ, self._watchdog, f"{name}.watchdog", order=ORDER_DEVICE)
        sched.every(AGENT_HZ, self._servo_agent, f"{name}.servo_agent", order=ORDER_DEVICE,
                    phase_ns=int(p / AGENT_HZ / 2))
        sched.on_tick(self._tick, f"{name}.tick", order=ORDER_HEARTBEAT)

    # -- the cores, as their processes run them -------------------------------
    def _plant(self, t_ns: int) -> None:
        self.plant.advance(1.0 / PLANT_HZ)

    def _servo(self, t_ns: int) -> None:
        if not self.alive["servo"]:
            return
        for msg in self._inbox:
            c = sw.unpack_command(msg)
            self.servo.command(c.mode, c.counts)
        self._inbox.clear()
        dacs = self.servo.step(self.bus.read_encoders_raw(), self.bus.read_limit_switches())
        self.bus.write_dacs(dacs)
        if self.servo.tick % sw.STATUS_EVERY_TICKS == 0:
            self._report = sw.pack_status(self.servo.status(), self.bus.amps_powered)
            self._report_t = t_ns

    def _watchdog(self, t_ns: int) -> None:
        if not self.alive["watchdog"] or self._report is None:
            return
        rep = sw.unpack_status(self._report)
        kick = self.watchdog.step(rep.tick, bool(rep.fault))
        if kick is not None:
            self.bus.write_watchdog(*kick)

    def _servo_agent(self, t_ns: int) -> None:
        if not self.alive["agent"]:
            return
        rep = sw.unpack_status(self._report) if self._report is not None else None
        fresh = rep is not None and t_ns - self._report_t < 3e9 / AGENT_HZ
        d = self.agent.step(self.ctrl_command.read(), rep, fresh)
        if d.message is not None:
            self._inbox.append(sw.pack_command(d.message))
        with self.ctrl_status.locked() as st:
            for k, v in d.status.items():
                st[k] = v
            st["fault"] = (int(st["fault"]) & ~MY_FAULTS) | d.fault_bits

    def _tick(self, tick: int) -> None:
        if self.alive["link"]:
            # droid-remote sends the Brain's command; droid-reis-agent copies it in
            cmd = self.brain_command.read()
            with self.ctrl_command.locked() as c:
                for src, dst in COMMAND_MAP.items():
                    c[dst] = cmd[src]
                c["brain_tick"] = tick
                c["link_alive"] = 1
            self.brain_command.update(sent=0)
        else:
            self.ctrl_command.update(link_alive=0, brain_tick=tick)
        if self.alive["planner"]:
            out = self.planner.step(self.ctrl_command.read(), self.ctrl_status.read())
            apply_plan(out, self.ctrl_command, self.ctrl_status, tick)
        if self.alive["link"]:
            # the reply: controller Status -> Brain Status, with forward kinematics (§4.1.8)
            st = self.ctrl_status.read()
            fields = {f: st[f] for f in ("encoder_pos", "encoder_cmd", "busy", "homed", "fault", "cmd_mode",
                                          "coord", "cmd_id", "cmd_result")}
            if int(st["homed"]):
                T = self.wcp_from_counts(st["encoder_pos"])
                fields.update(x=T[0, 3], y=T[1, 3], z=T[2, 3], R=T[:3, :3])
            self.brain_status.update(tick=tick, stale=0, **fields)

    def restart_servo(self, home_offset_deg=None) -> None:
        """Restart droid-servo with calibrated switch positions (the robot file's plus
        ``home_offset_deg``): the new servo starts unhomed, as a restarted program does."""
        self.home_offset_deg = np.zeros(6) if home_offset_deg is None else np.asarray(home_offset_deg, float)
        self.servo_params = ServoParams.from_robot(self.model, home_offset_deg)
        self.servo = ServoCore(self.servo_params)
        self._inbox.clear()

    # -- what a task program sees --------------------------------------------
    def wcp_from_counts(self, counts) -> np.ndarray:
        return self.model.fk(self.model.gearing.counts_to_joints(np.asarray(counts, float)))

    def wcp_global(self) -> np.ndarray:
        """The true wrist-centre pose [mm, global frame] (the world's arm-twin interface): the
        true arm (its D-H errors) at its true link angles (after the drives' deflection)."""
        if self.plant.params.dh_error.zero:
            return self.model.fk(self.plant.joint_deg)
        return self.model.base @ self.plant.wcp_true()

    def truth(self) -> dict:
        """The world's truth about this arm, as ``droid-sim truth ARM --json`` prints it."""
        from droid.sim.reis.truth import truth_dict

        return truth_dict(self.name, self.plant.time_s, self.plant.joint_deg, self.wcp_global()[:3, 3])

    @property
    def status(self):
        return self.brain_status.read()

    def _write(self, **fields) -> int:
        with self.brain_command.locked() as c:
            cmd_id = int(c["cmd_id"]) + 1
            for k, v in fields.items():
                c[k] = v
            c["cmd_id"], c["sent"] = cmd_id, 1
        return cmd_id

    def command_home(self) -> int:
        return self._write(cmd_mode=HOME_MODE, coord=JSPACE)

    def command_joint(self, counts, seconds: float) -> int:
        return self._write(encoder_pos=np.asarray(counts, np.int32), coord=JSPACE, cmd_mode=NORMAL_MODE,
                           joint_time_count=int(round(seconds * self.sched.heartbeat_hz)))

    def command_cart(self, T, seconds: float) -> int:
        T = np.asarray(T, float)
        return self._write(x=T[0, 3], y=T[1, 3], z=T[2, 3], R=T[:3, :3], coord=CARTSPACE,
                           cmd_mode=NORMAL_MODE, cart_time_count=int(round(seconds * self.sched.heartbeat_hz)))

    def set_normal(self) -> None:
        self.brain_command.update(cmd_mode=NORMAL_MODE)

    def run_until(self, pred, max_s: float, step_s: float = 0.05) -> bool:
        """Advance virtual time until ``pred()`` or ``max_s`` simulated seconds."""
        t_end = self.sched.t_ns + int(max_s * 1e9)
        while self.sched.t_ns < t_end:
            if pred():
                return True
            self.sched.run_for(step_s)
        return bool(pred())

    def home(self, max_s: float = 60.0) -> bool:
        cmd_id = self.command_home()
        ok = self.run_until(lambda: int(self.status["cmd_id"]) == cmd_id and int(self.status["homed"])
                            and int(self.status["busy"]) == 0, max_s)
        if ok:
            self.set_normal()
        return ok

    def move_done(self, cmd_id: int, max_s: float) -> bool:
        return self.run_until(lambda: int(self.status["cmd_id"]) == cmd_id and int(self.status["busy"]) == 0,
                              max_s)


def arms_from_cell(sched: Scheduler, cell, seed: int | None = None) -> dict[str, LockstepArm]:
    """The cell file's Reis arms (its ``reis_vme`` world devices) as lockstep arms on ``sched``.

    Each arm reads its subunit's robot file and base; its plant carries the device table's
    world errors (``home_error_deg``, ``calibration_seed``, ``link_error_mm``,
    ``twist_error_deg``; droid.sim.reis.world), and a device naming a different robot file
    than its subunit is refused, as droid-sim refuses it.
    """
    from droid.cli import BadInput
    from droid.sim.reis.world import device_subunit, world_errors
    from droid.subunits.reis.robot_file import read_offsets

    arms = {}
    world_seed = int(cell.world.get("seed", 0)) if seed is None else seed
    for name, opts in cell.world.get("devices", {}).items():
        if not isinstance(opts, dict) or opts.get("type") != "reis_vme":
            continue
        opts = {k: v for k, v in opts.items() if k != "type"}
        where, sub = device_subunit(cell, name, opts)
        model = load_robot(sub.robot)
        home_error, dh_error = world_errors(where, model, opts)
        pp = ReisPlantParams(robot=sub.robot, home_error_deg=home_error, dh_error=dh_error)
        try:  # droid-calibrate's offsets, where droid-servo finds them
            offsets = read_offsets(cell, sub.name)
        except ValueError as exc:
            raise BadInput(str(exc)) from None
        arms[sub.name] = LockstepArm(sched, sub.name, robot=sub.robot, base=tuple(sub.base),
                                     seed=int(opts.get("seed", world_seed)), plant_params=pp,
                                     home_offset_deg=offsets)
    return arms
