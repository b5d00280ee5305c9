"""One cycle of each Reis program around its core: read -> core.step -> write (ros2_control style).

Shared by the real-time shells and the lockstep arm (:class:`droid.sim.reis.cell.LockstepArm`),
so both modes run exactly the same code between the messages, the VME cards,
the records and the cores (docs/design.md §10 "one cycle, two runners"); the shells
only open the sockets, the driver and the databases, and keep time:

* :class:`ServoStation` -- droid-servo, 500 Hz: command messages in (§4.1.5.2); encoders
  and switches -> :class:`ServoCore` -> DACs; a status message every ``STATUS_EVERY_TICKS``;
* :class:`WatchdogStation` -- droid-watchdog, 50 Hz: the servo's status messages in; kick
  the watchdog registers (§2.3, §4.1.4); AMP_STATUS -> the WATCHDOG fault bit of ctrl_status;
* :class:`ServoAgentStation` -- droid-servo-agent, 60 Hz: ctrl_command + the servo's newest
  fresh status -> one command message; status fields and fault bits -> ctrl_status (§4.1.6);
* :class:`PlannerStation` -- droid-planner, per relayed tick: ctrl_command + ctrl_status ->
  way-point, busy (§4.1.7).

The agent copier (droid-reis-agent) is :class:`droid.subunits.agent.AgentStation`, the
remote's cycle :class:`droid.brain.runtime.remote.RemoteStation`.
"""
from __future__ import annotations

from droid.brain.db.layouts import FAULT_WATCHDOG
from droid.subunits.reis import servo_wire as sw
from droid.subunits.reis import vme_map as vm
from droid.arm.planner import PlannerStation  # droid-planner: the neutral arm's, run by the Reis
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.servo_agent import ServoAgentStation
from droid.subunits.reis.vme import VmeBus
from droid.subunits.reis.watchdog import WatchdogCore

__all__ = ["ServoStation", "WatchdogStation", "ServoAgentStation", "PlannerStation"]


class ServoStation:
    """droid-servo's cycle: ``take`` each command message as it arrives, ``cycle`` every 2 ms.

    ``bus`` is a :class:`~droid.subunits.reis.vme.VmeBus` (the driver over the cards' registers).
    """

    def __init__(self, core: ServoCore, bus) -> None:
        self.core = core
        self.bus = bus
        self.bad_frames = 0  # malformed command messages dropped
        self.raw: tuple[int, ...] | None = None  # the last encoder registers read [counts, 16 bit]
        self.dacs: tuple[int, ...] | None = None  # the last DAC values written [DAC counts]
        # the registers' bytes for the core's one-call tick (ServoCore.step_registers), on VmeBus only
        self._regs = bus.registers if type(bus) is VmeBus else None

    def take(self, msg: bytes) -> bool:
        """One command message from the servo agent (the servo planner, §4.1.5.2); True if the
        core took it as a new command, False if it was ignored or malformed (counted)."""
        try:
            c = sw.unpack_command(msg)
            return self.core.command(c.mode, c.counts)
        except (sw.BadServoMessage, ValueError):
            self.bad_frames += 1
            return False

    def cycle(self, periods: int = 1) -> bytes | None:
        """Read encoders and switches, step the core, write the DACs (§4.1.5.1).  Returns the
        status message to publish (every ``STATUS_EVERY_TICKS`` servo ticks), else None.
        ``periods`` > 1 after a stalled host (timer overrun).  Driver errors propagate."""
        bus, core = self.bus, self.core
        if periods == 1 and self._regs is not None:
            got = core.step_registers(self._regs)  # the same reads, bits and writes as below, in one call
            if got is not None:
                self.raw, self.dacs = got
                if core.tick % sw.STATUS_EVERY_TICKS == 0:
                    return core.status_message(bus.amps_powered)
                return None
        self.raw = bus.read_encoders_raw()
        self.dacs = core.step(self.raw, bus.read_limit_switches(), periods)
        bus.write_dacs(self.dacs)
        if core.tick % sw.STATUS_EVERY_TICKS == 0:
            return core.status_message(bus.amps_powered)  # = sw.pack_status(core.status(), ...)
        return None


class WatchdogStation:
    """droid-watchdog's cycle: ``take`` the servo's status messages, ``cycle`` at 50 Hz.

    The amplifiers are powered only once the servo runs and holds the arm (§4.1.4: "the
    operator can safely enable the servo motors without having unwanted motion"): no kick
    before the servo's first status.  With ``ctrl_status`` (the controller's Status record)
    the cards' AMP_STATUS latch is reported as its FAULT_WATCHDOG bit, written on change.
    """

    def __init__(self, core: WatchdogCore, bus, ctrl_status=None) -> None:
        self.core = core
        self.bus = bus
        self.ctrl_status = ctrl_status
        self.servo_tick: int | None = None  # the servo's heartbeat (its tick), once heard
        self.servo_fault = False
        self.bad_frames = 0
        self.latched: bool | None = None  # the amplifiers' latch as last reported

    def take(self, msg: bytes) -> None:
        """One status message of the servo (malformed ones are counted and dropped)."""
        try:
            rep = sw.unpack_status(msg)
        except sw.BadServoMessage:
            self.bad_frames += 1
            return
        self.observe(rep.tick, bool(rep.fault))

    def observe(self, servo_tick: int, servo_fault: bool) -> None:
        """The servo's tick and fault (from its status message, or read off a core in a bench)."""
        self.servo_tick, self.servo_fault = servo_tick, servo_fault

    def cycle(self) -> bool:
        """Kick (or not); report the latch.  Returns True while it kicks."""
        kick = self.core.step(self.servo_tick, self.servo_fault) if self.servo_tick is not None else None
        if kick is not None:
            self.bus.write_watchdog(*kick)
        if self.ctrl_status is not None:
            latched = bool(self.bus.read_amp_status() & vm.AMP_STATUS_WATCHDOG_FAULT)
            if latched != self.latched:
                self.latched = latched
                with self.ctrl_status.locked() as st:
                    f = int(st["fault"])
                    st["fault"] = (f | FAULT_WATCHDOG) if latched else (f & ~FAULT_WATCHDOG)
                    self.ctrl_status.mark_written()
        return kick is not None
