"""The position command queue and its cache (thesis §4.1.5.1, §4.1.5.2).

The servo consumes one way-point per tick from the *queue*; the servo
planner puts the next command's ramp in the *cache*.  When the queue is used
up the cache is copied in; when the cache is empty the emergency *braking*
profile is loaded instead (decelerate at a fixed rate to zero, then hold).

DROID keeps that structure and fixes one thing the thesis glosses over
("500Hz/60Hz ≈ 8"): a 60 Hz command lasts 8.33 servo ticks, not 8.  Eight
fixed steps per command would leave the queue empty once every three commands
(braking every 50 ms), and 8-or-9-step ramps would modulate the velocity by
±6 %.  So a command's ramp spans exactly one command period on an exact
integer time line (:mod:`servo_planner`): 8 or 9 way-points, constant
velocity, no drift.  A command that is late by up to ``starve_grace_ticks``
is bridged by *coasting* (extrapolating the last velocity); when it arrives,
the way-points the coast already covered are skipped, so the path stays on
the planned ramp.  Only a longer gap brakes.  A command that arrives while the
cache is still full replaces it (newest wins).
"""
from __future__ import annotations

from fractions import Fraction

import numpy as np

from droid.subunits.reis.servo_params import ServoParams
from droid.subunits.reis.servo_planner import braking_profile, linear_ramp, max_reach_counts

N = 6


class CommandQueue:
    """Queue + cache + braking for six joints.  Positions in extended counts."""

    def __init__(self, params: ServoParams):
        ratio = Fraction(params.servo_rate_hz).limit_denominator(10**6) / Fraction(
            params.command_rate_hz
        ).limit_denominator(10**6)
        self.period_num = ratio.numerator  # command period = num/den servo ticks
        self.period_den = ratio.denominator
        self.brake_steps = params.queue_steps
        self.grace_ticks = params.starve_grace_ticks
        self._max_speed = np.asarray(params.max_speed_counts_per_tick, np.int64)
        # the speed limit's reach per command period [counts] (servo_planner.limit_target's, once)
        self._reach = max_reach_counts(self._max_speed, self.period_num, self.period_den)
        # velocity change allowed per command period for JOG: a * P^2 [counts per period]
        period = self.period_num / self.period_den
        self._jog_dv = np.floor(np.asarray(params.jog_accel_counts_per_tick2, float) * period * period)
        self._decel = np.asarray(params.brake_decel_counts_per_tick2, float)
        self.reset(np.zeros(N, np.int64), 0)

    def reset(self, position: np.ndarray, tick: int) -> None:
        """Empty queue and cache, hold ``position`` [counts] (bumpless start)."""
        self._queue = np.asarray(position, np.int64)[None, :].copy()
        self._qi = 1  # exhausted
        self._tail = np.asarray(position, np.int64).copy()  # where the queue / last ramp ends
        self._cache_full = False
        self._cache_origin = self._tail.copy()
        self._cache_goal = self._tail.copy()
        self._seg_end_sub = tick * self.period_den  # end of the current ramp's period
        self._coast = 0
        self._starved = True  # braking profile (or its hold) in use
        self._brake_pos = self._tail.astype(float)
        self._brake_vel = np.zeros(N)
        self._disp = np.zeros(N, np.int64)  # displacement of the last ramp [counts per period]
        self._disp_before_cache = self._disp.copy()

    # -- status ----------------------------------------------------------------
    @property
    def starved(self) -> bool:
        """The queue ran dry: the braking profile (or its final hold) is in use."""
        return self._starved

    @property
    def braking(self) -> bool:
        """Starved and still decelerating."""
        return self._starved and bool((self._brake_vel != 0.0).any())

    @property
    def last_goal(self) -> np.ndarray:
        """The last commanded target [counts] (the base of a JOG command)."""
        return (self._cache_goal if self._cache_full else self._tail).copy()

    @property
    def origin(self) -> np.ndarray:
        """Where the next ramp starts [counts]."""
        return (self._cache_origin if self._cache_full else self._tail).copy()

    # -- the planner side (command rate) ------------------------------------------
    def submit(self, goal, accel_limit: bool = False) -> np.ndarray:
        """Put a ramp to ``goal`` [counts] in the cache, limited to the joints'
        maximum speed and, with ``accel_limit`` (JOG), to a velocity change of
        ``jog_accel_counts_per_tick2``; returns the goal actually planned."""
        origin = self.origin
        if not self._cache_full:
            self._disp_before_cache = self._disp
        goal = np.asarray(goal, np.int64)
        if accel_limit:
            prev = self._disp_before_cache
            disp = np.clip(goal - origin, prev - self._jog_dv, prev + self._jog_dv).astype(np.int64)
            goal = origin + disp
        reach = self._reach  # limit_target(origin, goal, max_speed, num, den), its reach computed once
        goal = np.minimum(np.maximum(goal, origin - reach), origin + reach)  # = np.clip for int64
        self._disp = goal - origin
        self._cache_origin = origin
        self._cache_goal = goal
        self._cache_full = True
        return goal.copy()

    # -- the servo side (every tick) ----------------------------------------------
    def next_target(self, tick: int, target: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """The way-point [counts] for servo tick ``tick``, given the previous tick's
        ``target`` and ``velocity`` [counts/tick]."""
        holding = self._starved and not (self._brake_vel != 0.0).any()
        if self._qi < len(self._queue) and not (holding and self._cache_full):
            self._qi += 1
            return self._queue[self._qi - 1].copy()
        if self._cache_full:
            return self._load_cache(tick)
        if not self._starved and self._coast < self.grace_ticks:
            self._coast += 1
            return target + velocity
        if not self._starved:
            self._starved = True
            self._brake_pos = target.astype(float)
            self._brake_vel = velocity.astype(float)
        self._coast = 0
        self._disp = np.rint(self._brake_vel * self.period_num / self.period_den).astype(np.int64)
        self._queue, self._brake_pos, self._brake_vel = braking_profile(
            self._brake_pos, self._brake_vel, self._decel, self.brake_steps
        )
        self._qi = 1
        self._tail = self._queue[-1].copy()
        self._seg_end_sub = (tick + self.brake_steps - 1) * self.period_den
        return self._queue[0].copy()

    def _load_cache(self, tick: int) -> np.ndarray:
        if self._starved:
            # a fresh start: the command came in since the last tick; its period
            # starts now (this tick still holds the origin), so it ends just after
            # the next command is due and the stream runs with up to a tick of lag
            start = tick * self.period_den
            ramp = linear_ramp(self._cache_origin, self._cache_goal, self.period_num, self.period_den, start)
            ramp = np.vstack([self._cache_origin[None, :], ramp])
        else:
            start = self._seg_end_sub
            ramp = linear_ramp(
                self._cache_origin, self._cache_goal, self.period_num, self.period_den, start, first_tick=tick
            )
            if len(ramp) == 0:  # the whole period was coasted through: jump to its end
                ramp = self._cache_goal[None, :].copy()
        self._queue = ramp
        self._qi = 1
        self._tail = self._cache_goal.copy()
        self._seg_end_sub = max(start + self.period_num, tick * self.period_den)
        self._cache_full = False
        self._coast = 0
        self._starved = False
        self._brake_vel = np.zeros(N)
        return ramp[0].copy()
