"""Lockstep runner for the Reis arm: plant, servo, watchdog and commands on virtual time.

A bench for the servo alone (no agents, no databases), on the one lockstep
scheduler, :class:`droid.sim.lockstep.Scheduler`.  Its public time is an
integer count of base ticks at the least common multiple of the rates (6 kHz
for 2000/500/50/60 Hz), never the wall clock.  At each instant the due
parties run in this order, as the real-time cell would see them:

1. the 60 Hz command source (the servo agent's role) calls ``servo.command``;
2. the 50 Hz watchdog station writes the watchdog registers (or not);
3. the 500 Hz servo station reads encoders/switches and writes the DACs;

and the plant is advanced (in 2 kHz substeps) up to the current instant before
anyone touches the register map, so every core sees the world as it is at
that instant and the world integrates the outputs written at that instant.
The stations (:mod:`droid.subunits.reis.station`, the same as droid-servo's and
droid-watchdog's) talk to the plant only through :class:`VmeBus` over
``plant.regs``: the same bytes a real-time shell would reach through ``shm://``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from droid.brain.cell.device import HEARTBEAT_HZ
from droid.subunits.reis.device import SERVO_HZ, WATCHDOG_HZ
from droid.sim.lockstep import ORDER_DEVICE, Scheduler
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.servo_params import Mode, ServoParams
from droid.subunits.reis.station import ServoStation, WatchdogStation
from droid.subunits.reis.vme import VmeBus
from droid.subunits.reis.watchdog import WatchdogCore

Command = tuple[Mode, Sequence[int]] | None
Commander = Callable[[int, float], Command]  # (command index, virtual time [s]) -> command or None


@dataclass(frozen=True)
class LockstepRates:
    plant_hz: int = 2000
    servo_hz: int = int(SERVO_HZ)  # droid.subunits.reis.device
    watchdog_hz: int = int(WATCHDOG_HZ)
    command_hz: int = int(HEARTBEAT_HZ)  # droid.brain.cell.device

    @property
    def base_hz(self) -> int:
        return math.lcm(self.plant_hz, self.servo_hz, self.watchdog_hz, self.command_hz)


@dataclass
class Trace:
    """Per-servo-tick record of a run (arrays, first axis = tick)."""

    t_s: np.ndarray
    encoder_pos: np.ndarray  # servo frame [counts]
    encoder_cmd: np.ndarray  # servo target, servo frame [counts]
    following_error: np.ndarray  # [counts]
    dac: np.ndarray  # [DAC counts]
    motor_counts: np.ndarray  # plant truth, home-relative [counts, float]
    joint_deg: np.ndarray  # plant truth [deg]
    encoder_raw: np.ndarray  # 16-bit registers [counts]
    starved: np.ndarray  # bool
    braking: np.ndarray  # bool
    homed: np.ndarray  # bool
    amps_on: np.ndarray  # bool

    def __len__(self) -> int:
        return len(self.t_s)


class ReisLockstep:
    """Steps a :class:`ReisPlant`, a :class:`ServoCore` and a :class:`WatchdogCore` on a
    :class:`~droid.sim.lockstep.Scheduler` (``self.sched``)."""

    def __init__(
        self,
        plant: ReisPlant,
        servo: ServoCore,
        watchdog: WatchdogCore | None = None,
        rates: LockstepRates | None = None,
    ):
        self.rates = rates if rates is not None else LockstepRates()
        r = self.rates
        base = r.base_hz
        every = {k: base // getattr(r, k) for k in ("plant_hz", "servo_hz", "watchdog_hz", "command_hz")}
        if any(base % getattr(r, k) for k in every):
            raise ValueError("rates must divide the base rate")
        if every["servo_hz"] % every["plant_hz"] or every["watchdog_hz"] % every["plant_hz"]:
            raise ValueError("plant rate must be a multiple of the servo and watchdog rates")
        if abs(plant.params.substep_s * r.plant_hz - 1.0) > 1e-9:
            raise ValueError(f"plant substep {plant.params.substep_s} s does not match {r.plant_hz} Hz")
        self.base_hz = base
        self.plant = plant
        self.servo = servo
        self.watchdog = watchdog if watchdog is not None else WatchdogCore()
        self.bus = VmeBus.from_buffer(plant.regs)
        self.servo_station = ServoStation(servo, self.bus)
        self.watchdog_station = WatchdogStation(self.watchdog, self.bus)
        self.tick = 0  # base ticks done
        self._plant_tick = 0  # plant substeps done
        self.command_index = 0
        self.servo_running = True  # False: the servo "process" is dead (DACs keep their last value)
        self.watchdog_running = True
        self._commander: Commander | None = None
        self._rows: list[tuple] | None = None
        # one scheduler; equal instants in the order command, watchdog, servo
        self.sched = Scheduler(heartbeat_hz=r.command_hz)
        self._command_task = self.sched.every(r.command_hz, self._command, "command", order=ORDER_DEVICE)
        self._watchdog_task = self.sched.every(r.watchdog_hz, self._watchdog, "watchdog", order=ORDER_DEVICE + 1)
        self._servo_task = self.sched.every(r.servo_hz, self._servo, "servo", order=ORDER_DEVICE + 2)

    @property
    def time_s(self) -> float:
        return self.tick / self.base_hz

    def _advance_plant(self, k: int, rate_hz: int) -> None:
        """Bring the plant to the instant ``k / rate_hz`` [s] (a whole number of substeps)."""
        target = k * self.rates.plant_hz // rate_hz
        n = target - self._plant_tick
        if n > 0:
            self.plant.advance(n * self.plant.params.substep_s)
            self._plant_tick = target

    def _command(self, t_ns: int) -> None:
        if self._commander is None:
            return
        cmd = self._commander(self.command_index, self._command_task.k / self.rates.command_hz)
        self.command_index += 1
        if cmd is not None:
            self.servo.command(*cmd)

    def _watchdog(self, t_ns: int) -> None:
        if not self.watchdog_running:
            return
        self._advance_plant(self._watchdog_task.k, self.rates.watchdog_hz)
        self.watchdog_station.observe(self.servo.tick, bool(self.servo.fault))
        self.watchdog_station.cycle()

    def _servo(self, t_ns: int) -> None:
        if not self.servo_running:
            return
        k = self._servo_task.k
        self._advance_plant(k, self.rates.servo_hz)
        st = self.servo_station
        st.cycle()
        if self._rows is not None:
            self._rows.append(self._row(k / self.rates.servo_hz, st.raw, st.dacs))

    def run(self, seconds: float, commander: Commander | None = None, record: bool = True) -> Trace | None:
        """Run ``seconds`` of virtual time; ``commander`` is called at the command rate."""
        end = self.tick + int(round(seconds * self.base_hz))
        self._commander, self._rows = commander, ([] if record else None)
        try:  # every instant before ``end`` (the end instant is the next run's first)
            self.sched.run_until((end * 10**9 + self.base_hz // 2) // self.base_hz - 1)
        finally:
            rows, self._commander, self._rows = self._rows, None, None
        self._advance_plant(end, self.base_hz)
        self.tick = end
        return self._trace(rows) if record else None

    def _row(self, t_s: float, raw, dacs) -> tuple:
        s, p = self.servo, self.plant
        return (
            t_s,
            s.encoder_pos,
            s.encoder_cmd,
            s.following_error,
            dacs,
            p.motor_counts,
            p.joint_deg,
            raw,
            s.starved,
            s.braking,
            s.homed,
            p.amps_on,
        )

    @staticmethod
    def _trace(rows: list[tuple]) -> Trace:
        if not rows:
            z6 = np.zeros((0, 6))
            zb = np.zeros(0, bool)
            return Trace(np.zeros(0), z6, z6, z6, z6, z6, z6, z6, zb, zb, zb, zb)
        cols = list(zip(*rows))
        return Trace(
            t_s=np.asarray(cols[0]),
            encoder_pos=np.asarray(cols[1], np.int64),
            encoder_cmd=np.asarray(cols[2], np.int64),
            following_error=np.asarray(cols[3], np.int64),
            dac=np.asarray(cols[4], np.int64),
            motor_counts=np.asarray(cols[5]),
            joint_deg=np.asarray(cols[6]),
            encoder_raw=np.asarray(cols[7], np.int64),
            starved=np.asarray(cols[8], bool),
            braking=np.asarray(cols[9], bool),
            homed=np.asarray(cols[10], bool),
            amps_on=np.asarray(cols[11], bool),
        )

    def close(self) -> None:
        self.bus.close()


# -- command sources (the 60 Hz servo agent's role in tests and benches) ------------------
def min_jerk_waypoints(start_counts, goal_counts, duration_s: float, rate_hz: float = 60.0) -> np.ndarray:
    """Way-points [counts, int64] at ``rate_hz`` along a minimum-jerk joint move
    (what droid-planner would send); row 0 is the first point after ``start``,
    the last row is exactly ``goal``."""
    start = np.asarray(start_counts, float)
    goal = np.asarray(goal_counts, float)
    n = max(1, int(round(duration_s * rate_hz)))
    s = np.arange(1, n + 1) / n
    blend = 10 * s**3 - 15 * s**4 + 6 * s**5
    pts = np.rint(start + (goal - start) * blend[:, None]).astype(np.int64)
    pts[-1] = np.rint(goal).astype(np.int64)
    return pts


def waypoint_commander(
    waypoints: np.ndarray, mode: Mode = Mode.NORMAL, first_index: int = 0, stop_after: int | None = None
) -> Commander:
    """Send ``waypoints[i]`` at command ``first_index + i``, then repeat the last one.

    ``stop_after``: send nothing from that many commands on (a dead agent).
    In JOG mode the rows are deltas and the repeat is a zero delta.
    """
    pts = np.asarray(waypoints, np.int64)

    def commander(index: int, _t: float) -> Command:
        i = index - first_index
        if stop_after is not None and i >= stop_after:
            return None
        if i < 0:
            return None
        if i < len(pts):
            return mode, tuple(int(x) for x in pts[i])
        if mode == Mode.JOG:
            return mode, (0,) * 6
        return mode, tuple(int(x) for x in pts[-1])

    return commander


def constant_commander(mode: Mode, counts=(0, 0, 0, 0, 0, 0)) -> Commander:
    """The same command every period (e.g. HOME, or a zero JOG to keep the queue fed)."""
    cmd = (mode, tuple(int(x) for x in counts))
    return lambda _index, _t: cmd


# -- a ready-made cell ---------------------------------------------------------------------
def make_reis_cell(
    seed: int = 0,
    plant_params: ReisPlantParams | None = None,
    servo_params: ServoParams | None = None,
    near_switch_offset_deg=None,
    **plant_kw,
) -> ReisLockstep:
    """Plant + servo + watchdog in lockstep.  ``near_switch_offset_deg`` (6 values)
    powers the arm up at switch + offset instead of the seeded random pose
    (homing then takes ~20 simulated seconds instead of ~25-30)."""
    pp = plant_params if plant_params is not None else ReisPlantParams()
    if near_switch_offset_deg is not None:
        plant_kw["initial_joint_deg"] = np.asarray(pp.switch_joint_deg) + np.asarray(near_switch_offset_deg)
    plant = ReisPlant(pp, seed=seed, **plant_kw)
    return ReisLockstep(plant, ServoCore(servo_params))


def run_homing(ls: ReisLockstep, max_s: float = 60.0, chunk_s: float = 0.5) -> list[Trace]:
    """Send HOME at the command rate until homed, a fault, or ``max_s``; returns the traces."""
    cmd = constant_commander(Mode.HOME)
    pieces = []
    t = 0.0
    while not ls.servo.homed and not ls.servo.fault and t < max_s:
        pieces.append(ls.run(chunk_s, cmd))
        t += chunk_s
    return pieces


def plants_same_bits(a, b) -> bool:
    """Two Reis plants hold the same bits: registers, simulated time and state (motor and link
    angles and speeds) -- an A/B comparison's verdict (bench_plant_ab, bench_kernel, the tests)."""
    return bytes(a.regs) == bytes(b.regs) and a.time_s == b.time_s and all(
        getattr(a, k).tobytes() == getattr(b, k).tobytes() for k in ("_theta", "_omega", "_q", "_qd"))


def drive_side_by_side(cells: dict[str, ReisLockstep], move_deg, moves: int, after_chunk,
                       max_homing_chunks: int = 120, on_homed=None) -> dict[str, Commander]:
    """Drive several Reis cells with the same commands, chunk by chunk (thesis §4.1.5: HOME, then
    way-points at the command rate): 0.05 s of power-up, HOME in 0.5 s chunks until every one is
    homed (``max_homing_chunks`` at most), then ``moves`` times a 2 s minimum-jerk move of every
    joint by ``move_deg`` [deg] and back, each followed by 2 s more; ``after_chunk()`` after every
    chunk (an A/B comparison's check), ``on_homed()`` once homing ended (a bench's phase mark).
    Returns each cell's last commander (it holds its target)."""
    for c in cells.values():
        c.run(0.05)
    after_chunk()
    home = constant_commander(Mode.HOME)
    for _ in range(max_homing_chunks):
        if all(c.servo.homed for c in cells.values()):
            break
        for c in cells.values():
            c.run(0.5, home, record=False)
        after_chunk()
    if on_homed is not None:
        on_homed()
    cmds: dict[str, Commander] = {n: home for n in cells}
    first = next(iter(cells.values()))
    step = np.rint(np.asarray(first.servo.params.joint_to_counts) @ np.asarray(move_deg, float)).astype(np.int64)
    for _ in range(moves):
        for sign in (1, -1):
            for n, c in cells.items():
                s0 = np.asarray(c.servo.encoder_cmd)
                cmds[n] = waypoint_commander(min_jerk_waypoints(s0, s0 + sign * step, 2.0), Mode.NORMAL,
                                             first_index=c.command_index)
            for _ in range(5):
                for n, c in cells.items():
                    c.run(0.5, cmds[n], record=False)
                after_chunk()
    return cmds


#: power-up pose a little off the home switches (both sides), so homing takes ~3 s simulated
#: before the edges are bracketed at rest (homing.py step 5: ~3 s more a joint)
NEAR_SWITCH_OFFSET_DEG = (0.4, -0.3, 0.3, -0.4, 0.3, -0.3)


def homed_rigid_cell(seed: int = 21):
    """A Reis lockstep cell on rigid drives, powered up near its switches and homed (the tests'
    starting point: the servo's count logic is exact there; the compliant arm's links spring
    back a few counts after a hard stop)."""
    from droid.sim.reis.plant import ReisPlantParams

    ls = make_reis_cell(seed=seed, near_switch_offset_deg=NEAR_SWITCH_OFFSET_DEG,
                        plant_params=ReisPlantParams(compliance=False))
    ls.run(0.05)
    run_homing(ls)
    if not ls.servo.homed:
        raise RuntimeError("the lockstep Reis cell did not home")
    return ls

