"""The 500 Hz servo core of the Reis motion controller (thesis §4.1.5, figures 4.7-4.10).

A shell does, every 2 ms::

    dacs = core.step(bus.read_encoders_raw(), bus.read_limit_switches())
    bus.write_dacs(dacs)

and, whenever a 60 Hz command message arrives from the servo agent::

    core.command(mode, encoder_cmd_counts)

Per tick (:meth:`ServoCore.step`, figure 4.8): extend the 16-bit counters to
unbounded counts (roll-over, :func:`droid.kinematics.gearing.extend_counter`);
pick the tick's target -- from the homing state machine while homing
(:mod:`homing`), else the next way-point of the position queue; when the queue
is used up the cache (the next command's ramp) is copied in, and when the
cache is empty too the emergency braking profile is loaded
(:mod:`command_queue`); clamp the target to the min/max counts (once homed);
run the PID with output limits and anti-windup (:mod:`pid`); check faults.

Per command (:meth:`ServoCore.command`, the servo planner, figure 4.9): the
target is the last command plus the jog delta (JOG) or the absolute command
(NORMAL, home-relative), clipped to the target limits and to the joint's
maximum speed, and planned as a linear ramp over one command period
(:mod:`servo_planner`: 8 or 9 way-points on an exact time line, since
500 Hz / 60 Hz = 8.33 -- see :mod:`command_queue` for why not a fixed 8).

Frames: internally every position is an *extended* count (the unbounded
encoder count).  Before homing, commands and status are in that frame
(thesis: "the non-homed situation copies the relative encoder commands to
the target values"); once homed they are relative to the zero found by
homing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from droid.subunits.reis import servo_wire as sw
from droid.subunits.reis.command_queue import CommandQueue
from droid.subunits.reis.homing import HomePhase, Homing, zero_from_edges
from droid.subunits.reis.pid import Pid
from droid.subunits.reis.servo_params import Fault, Mode, ServoParams

N = 6


@dataclass(frozen=True)
class ServoStatus:
    """A snapshot for the servo agent (thesis Table 4.2 fields the servo owns)."""

    tick: int  # servo ticks since start (also the liveness heartbeat)
    mode: Mode
    homed: bool
    homing_joint: int  # 0-based joint being homed, -1 when not homing
    starved: bool  # the queue ran dry: braking profile (or its final hold) in use
    braking: bool  # starved and the commanded velocity is not yet zero
    fault: Fault
    encoder_pos: tuple[int, ...]  # [counts] home-relative once homed
    encoder_cmd: tuple[int, ...]  # [counts] this tick's target, same frame
    following_error: tuple[int, ...]  # target - position [counts]
    dac: tuple[int, ...]  # last output [DAC counts]


class ServoCore:
    """Six-joint servo: queue + cache, planner, braking, PID, homing.  No I/O."""

    def __init__(self, params: ServoParams | None = None, *, kernel: str | None = None):
        """``kernel``: "c" or "python" overrides ``DROID_KERNEL`` for the PID (droid.kernel; tests)."""
        p = self.params = params if params is not None else ServoParams()
        self._tmin = np.asarray(p.target_min_counts, np.int64)
        self._tmax = np.asarray(p.target_max_counts, np.int64)
        self._fe_max = [float(x) for x in p.max_following_error_counts]
        self._fe_max_arr = np.array(self._fe_max)  # the compiled kernel's copy
        self._pid = Pid(
            p.kp_dac_per_count,
            p.ki_dac_per_count_tick,
            p.kd_dac_per_count_per_tick,
            p.integral_limit_dac,
            p.dac_min_counts,
            p.dac_max_counts,
            kernel=kernel,
        )
        self._homing = Homing(p)
        self._mode = Mode.NORMAL  # hold position until told otherwise (thesis: waits for HOME)
        self._fault = Fault.NONE
        self._last_command_mode: Mode | None = None
        self._zero: np.ndarray | None = None
        self._limits: tuple[np.ndarray, np.ndarray] | None = None  # zero + tmin, zero + tmax once homed
        self._span = 1 << int(p.encoder_bits)  # the counters' range [counts]
        self._tick = 0
        self._pos: np.ndarray | None = None  # extended counts
        self._target = np.zeros(N, np.int64)
        self._vel = np.zeros(N, np.int64)  # target increment of the last tick [counts/tick]
        self._dac = (0,) * N
        self._queue = CommandQueue(p)
        self.refused_resumes = 0  # NORMAL way-points refused after the brake (resume_window_counts)

    # -- status ------------------------------------------------------------------
    # Alike in shape only to other read-only views (WatchdogCore's, SerialPort's): the core's own state.
    @property
    def tick(self) -> int:
        """Servo ticks executed (the heartbeat a watchdog shell can supervise)."""
        return self._tick

    @property
    def mode(self) -> Mode:
        return self._mode

    @property
    def homed(self) -> bool:
        return self._zero is not None

    @property
    def homing(self) -> bool:
        return self._homing.active

    @property
    def homing_joint(self) -> int | None:
        """0-based joint being homed, or None."""
        return self._homing.joint

    @property
    def fault(self) -> Fault:
        return self._fault

    @property
    def starved(self) -> bool:
        """The command stream ran dry: braking (or holding after braking)."""
        return self._queue.starved

    @property
    def braking(self) -> bool:
        """Starved and still decelerating."""
        return self._queue.braking

    @property
    def at_rest(self) -> bool:
        """Starved, and the braking profile has run out: the target stood still last tick."""
        return self._queue.starved and not self._queue.braking and not self._vel.any()

    @property
    def home_edge_joints_deg(self) -> np.ndarray | None:
        """The joint angles [deg, servo frame] at each joint's switch edge of the last homing
        (row i: the pose when joint i's edge was found), or None before homing.  Calibration
        uses them to know the pose -- and so the drives' load -- of each edge (§4.1.1.4)."""
        if self._zero is None:
            return None
        minv = np.linalg.inv(np.asarray(self.params.joint_to_counts, float))
        return (np.asarray(self._homing.edges, float) - self._zero) @ minv.T

    @property
    def zero_counts(self) -> tuple[int, ...] | None:
        """Encoder zero [extended counts] found by homing, or None."""
        return None if self._zero is None else tuple(int(x) for x in self._zero)

    def _frame(self, counts: np.ndarray) -> tuple[int, ...]:
        """``counts`` relative to home once homed, as Python ints (subtracted as ints: exact, as
        int64's are, and cheaper than an array operation at six values; every 4th servo tick)."""
        if self._zero is None:
            return tuple(counts.tolist())
        return tuple([c - z for c, z in zip(counts.tolist(), self._zero.tolist())])

    @property
    def encoder_pos(self) -> tuple[int, ...]:
        """Measured positions [counts]: relative to home once homed, else extended raw."""
        if self._pos is None:
            return (0,) * N
        return self._frame(self._pos)

    @property
    def encoder_cmd(self) -> tuple[int, ...]:
        """This tick's target [counts], same frame as :attr:`encoder_pos`."""
        return self._frame(self._target)

    @property
    def following_error(self) -> tuple[int, ...]:
        """target - position [counts]."""
        if self._pos is None:
            return (0,) * N
        return tuple([t - p for t, p in zip(self._target.tolist(), self._pos.tolist())])

    def flight_sample(self) -> tuple:
        """This tick for droid-servo's flight record: positions and target [extended counts] as the
        bytes of their int64 arrays (copies; zeros before the first read), DAC words [DAC counts]
        -- two memcpys and a reference, a tenth of a microsecond at 500 Hz."""
        pos = self._pos
        return (pos.tobytes() if pos is not None else bytes(8 * N), self._target.tobytes(), self._dac)

    @property
    def dac(self) -> tuple[int, ...]:
        """Last output [DAC counts]."""
        return self._dac

    @property
    def integral_dac(self) -> tuple[float, ...]:
        """PID integral terms [DAC counts] (for anti-windup checks)."""
        return tuple(float(x) for x in self._pid.integral)

    def status(self) -> ServoStatus:
        """The snapshot (every 4th tick) through the properties above."""
        return ServoStatus(
            tick=self._tick,
            mode=self._mode,
            homed=self.homed,
            homing_joint=-1 if self.homing_joint is None else self.homing_joint,
            starved=self._queue.starved,
            braking=self._queue.braking,
            fault=self._fault,
            encoder_pos=self.encoder_pos,
            encoder_cmd=self.encoder_cmd,
            following_error=self.following_error,
            dac=self._dac,
        )

    def status_message(self, amps_on: bool) -> bytes:
        """``servo_wire.pack_status(self.status(), amps_on)``, the same bytes, without the
        snapshot and its properties (every 4th servo tick of droid-servo and of every lockstep
        trial, issue 44): the 18 counts in plain ints, framed as :meth:`_frame` frames them."""
        pos, zero = self._pos, self._zero
        k = self._pid._k
        if k is not None and pos is not None:  # the compiled kernel's packing (the same bytes)
            joint, q = self._homing.joint, self._queue
            msg = k.servo_status(self._tick, int(self._mode), -1 if joint is None else int(joint), int(q.starved),
                                 int(q.braking), int(self._fault), int(bool(amps_on)), pos, self._target, zero,
                                 self._dac)
            if msg is not None:
                return msg
        t = self._target.tolist()
        if pos is None:
            p = fe = [0] * N
        else:
            p = pos.tolist()
            fe = [a - b for a, b in zip(t, p)]
        if zero is not None:
            zl = zero.tolist()
            t = [a - b for a, b in zip(t, zl)]
            if pos is not None:
                p = [a - b for a, b in zip(p, zl)]
        joint = self._homing.joint
        q = self._queue
        return sw.pack_status_values(self._tick, int(self._mode), int(zero is not None),
                                     -1 if joint is None else int(joint), int(q.starved), int(q.braking),
                                     int(self._fault), int(bool(amps_on)), p + t + fe, self._dac)

    # -- commands (60 Hz, the servo planner) ---------------------------------------
    def command(self, mode: Mode | int, encoder_cmd_counts=(0, 0, 0, 0, 0, 0)) -> bool:
        """A command message from the servo agent; returns False if it was ignored.

        OFF disables (and clears a fault); HOME starts homing when the command
        mode changes to HOME (the agent repeats it every period; repeats are
        ignored, also after homing has finished); JOG adds
        ``encoder_cmd_counts`` to the last command; NORMAL takes them as
        absolute home-relative counts (only once homed).  JOG/NORMAL are
        ignored while homing; everything but OFF is ignored after a fault and
        before the first :meth:`step`.
        """
        mode = Mode(mode)
        if mode == Mode.OFF:
            self._last_command_mode = mode
            self._mode = Mode.OFF
            self._fault = Fault.NONE
            self._homing.abort()
            return True
        if self._pos is None or self._fault != Fault.NONE:
            return False
        previous, self._last_command_mode = self._last_command_mode, mode
        if mode == Mode.HOME:
            # edge-triggered: the agent repeats HOME every period until the brain
            # changes cmd_mode; only a change into HOME (re)starts homing
            if previous != Mode.HOME and not self._homing.active:
                self._start_homing()
            return True
        if self._homing.active or (mode == Mode.NORMAL and self._zero is None):
            return False
        cmd = np.asarray(encoder_cmd_counts, np.int64)
        if cmd.shape != (N,):
            raise ValueError(f"encoder command needs {N} counts, got shape {cmd.shape}")
        if self._mode == Mode.OFF:
            self._hold_here()
        self._mode = mode
        goal = self._queue.last_goal + cmd if mode == Mode.JOG else cmd + self._zero
        if self._zero is not None:
            lo, hi = self._limits
            goal = np.minimum(np.maximum(goal, lo), hi)  # np.clip(goal, lo, hi) for int64, without its wrapper
        if (mode == Mode.NORMAL and self.at_rest
                and np.any(np.abs(goal - self._pos) > self.params.resume_window_counts)):
            # braked to rest, and the way-point is not where the arm stands: a stale target
            # (its sender missed the stop); resuming would jump to it at full ramp speed.
            # (While the brake still runs, a way-point continuing the path is taken: a late
            # command stream rides through, as §4.1.5.1's cache does.)
            self.refused_resumes += 1
            return False
        self._queue.submit(goal, accel_limit=mode == Mode.JOG)
        return True

    # -- the 500 Hz tick -------------------------------------------------------------
    def step(self, encoders_raw, limit_switches, periods: int = 1) -> tuple[int, ...]:
        """One servo tick: six raw 16-bit counters [counts] and six switch states
        -> six DAC values [DAC counts, -2048..2047].  ``periods`` > 1 after the host
        stalled the loop (timer overrun): the encoders may then legitimately have
        moved ``periods`` times farther (docs/design.md §9: ride through a stall).

        The hot loop of the servo program and of every lockstep trial (issue 13 item 6):
        per-joint work is done in plain Python ints/floats and the few numpy calls on the
        six-element target work in place -- at this size a numpy call costs more than the
        arithmetic."""
        self._tick += 1
        self._read_encoders(encoders_raw, int(periods) if periods > 1 else 1)
        if self._mode == Mode.OFF or self._fault != Fault.NONE:
            self._hold_here()
            self._pid.reset()
            self._dac = (0,) * N
            return self._dac
        previous = self._target
        if self._homing.active:
            previous = previous.copy()  # homing moves the target in place
            phase = self._homing.step(self._pos, limit_switches, self._target)
            if phase == HomePhase.DONE:
                self._finish_homing()
            elif phase == HomePhase.FAILED:
                self._fault = Fault.HOME_SWITCH_NOT_FOUND
        else:
            self._target = self._queue.next_target(self._tick, previous, self._vel)
            if self._target is previous:
                previous = previous.copy()
        target = self._target
        dac = self._tail(target, previous)
        if dac is None:
            self._fault = Fault.FOLLOWING_ERROR
        if self._fault != Fault.NONE:  # this one, or homing's switch not found
            self._pid.reset()
            self._dac = (0,) * N
            return self._dac
        self._dac = dac
        return self._dac

    def step_registers(self, regs) -> tuple[tuple[int, ...], tuple[int, ...]] | None:
        """:meth:`step` of one period with the encoders read from and the DACs written to the VME
        map's bytes ``regs`` (ServoStation.cycle: ``bus.read_encoders_raw()``, ``step``,
        ``bus.write_dacs``), in one call of the compiled kernel (droid/_kernel.c ``servo_cycle``:
        the same operations, the same bits and the same state after it) on the tick's common path:
        homed or not, a NORMAL or JOG stream with a way-point left in the queue or a new one in
        the cache (its ramp loaded here first, as ``next_target`` loads it), no fault, no
        homing.  Returns (the encoder registers read, the DAC words), or None with nothing read,
        written or changed where the tick leaves that path (or without the compiled kernel): the
        caller then runs the Python reference."""
        k = self._pid._k
        if k is None or self._pos is None or self._homing.active or self._mode == Mode.OFF or self._fault != Fault.NONE:
            return None
        q = self._queue
        qi = q._qi
        load = qi >= len(q._queue) or (q._starved and q._cache_full and not (q._brake_vel != 0.0).any())
        if load and not q._cache_full:
            return None  # CommandQueue.next_target's other branches: the coast, the brake
        jump = self.params.max_encoder_step_counts
        if type(jump) is not int:
            return None
        if load:
            # next_target's cache branch (a new way-point, every 8-9 ticks): its ramp loaded as
            # next_target loads it for this tick, then taken from the queue's head by the kernel --
            # next_target's very result (ramp[0]) and state (qi 1).  Should the kernel hand the
            # tick back, the reference's next_target takes the same head: the same tick either way.
            q._load_cache(self._tick + 1)
            q._qi = qi = 0
        pid = self._pid
        lo, hi = self._limits if self._limits is not None else (None, None)
        got = k.servo_cycle(regs, self._pos, q._queue, qi, self._target, self._vel, lo, hi, self._fe_max_arr,
                            pid._gains, pid._state, pid._first, self._span, jump)
        if got is None:  # an encoder jump or a following error: the reference takes the fault
            return None
        self._tick += 1
        q._qi = qi + 1
        pid._first = False
        self._dac = got[1]
        return got

    def _tail(self, target: np.ndarray, previous: np.ndarray) -> tuple[int, ...] | None:
        """The tick after the target is picked: clip it to the min/max counts once homed, the
        velocity [counts/tick], the following-error check (None when an error is over its limit)
        and the PID's DAC words, rounded -- in the compiled kernel when it is in use (droid.kernel:
        the same operations, the same bits), else here."""
        pid = self._pid
        if pid._k is not None:
            lo, hi = self._limits if self._limits is not None else (None, None)
            self._vel = np.empty(N, np.int64)
            return pid.tail_compiled(target, previous, lo, hi, self._pos, self._fe_max_arr, self._vel)
        if self._limits is not None:  # clip in place
            lo, hi = self._limits
            np.minimum(np.maximum(target, lo, out=target), hi, out=target)
        self._vel = target - previous
        error = (target - self._pos).tolist()
        for e, limit in zip(error, self._fe_max):
            if e > limit or -e > limit:
                return None
        return pid.step_rounded(error)

    def _read_encoders(self, encoders_raw, periods: int = 1) -> None:
        k, jump = self._pid._k, self.params.max_encoder_step_counts * periods
        if k is not None and self._pos is not None and type(jump) is int:  # the compiled kernel (droid.kernel)
            new = np.empty(N, np.int64)
            if k.extend_counters(self._pos, encoders_raw, self._span, jump, new):
                self._fault = Fault.ENCODER_JUMP
            self._pos = new
            return
        raw = [int(x) for x in encoders_raw]
        if len(raw) != N:
            raise ValueError(f"need {N} encoder values, got {len(raw)}")
        if self._pos is None:
            self._pos = np.asarray(raw, np.int64)
            self._hold_here()
            return
        jump = self.params.max_encoder_step_counts * periods
        span = self._span
        half = span >> 1
        new = []
        append = new.append
        jumped = False
        for p, r in zip(self._pos.tolist(), raw):  # extend_counter, inlined (six calls cost more)
            delta = (r - p) % span
            if delta >= half:
                delta -= span
            if delta > jump or -delta > jump:
                jumped = True
            append(p + delta)
        if jumped:
            self._fault = Fault.ENCODER_JUMP
        self._pos = np.array(new, np.int64)

    def _hold_here(self) -> None:
        """Targets := measured positions; queue and cache emptied (bumpless)."""
        self._target = self._pos.copy()
        self._vel = np.zeros(N, np.int64)
        self._queue.reset(self._pos, self._tick)

    # -- homing --------------------------------------------------------------------------
    def _start_homing(self) -> None:
        self._zero = None
        self._limits = None
        self._mode = Mode.HOME
        self._hold_here()
        self._pid.reset()
        self._homing.start()

    def _finish_homing(self) -> None:
        p = self.params
        self._zero = zero_from_edges(self._homing.edges, p.home_switch_deg, p.joint_to_counts)
        self._limits = (self._zero + self._tmin, self._zero + self._tmax)
        self._mode = Mode.NORMAL
        self._queue.reset(self._target, self._tick)
