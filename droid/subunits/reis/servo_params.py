"""Parameters, modes and faults of the Reis servo core (thesis §4.1.5).

Every constant of the servo, planner, braking and homing logic is a field of
:class:`ServoParams`, with its unit in the name.  Per-joint values are
6-tuples, joint 1 first.  Counts are motor encoder counts; "tick" is one servo
period (1/500 s).  The defaults are DROID's choices for the Reis V15 (the
thesis prints no gains or limits); docs/reis.md explains them.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import IntEnum
from pathlib import Path

import numpy as np

from droid.brain.cell.device import HEARTBEAT_HZ
from droid.brain.db.layouts import CmdMode
from droid.kinematics import load_robot
from droid.subunits.reis.device import SERVO_HZ
from droid.subunits.reis.robot_file import DEFAULT_ROBOT, joint_to_counts_tuple, load_gearing

Six = tuple[float, float, float, float, float, float]
SixInt = tuple[int, int, int, int, int, int]

#: The servo's command modes are the controller's ``cmd_mode`` numbers (Table 4.3, thesis §3.3):
#: one definition, :class:`droid.brain.db.layouts.CmdMode` (OFF 0, JOG 1, HOME 2, NORMAL 3).  The
#: servo agent passes ``cmd_mode`` through to the servo message unchanged.
#: OFF: servo disabled, DACs 0, targets follow the encoders (bumpless restart); HOME: run the
#: homing state machine (§4.1.5.3); JOG: the encoder command is relative to the last command
#: (§4.1.5.2); NORMAL: absolute, relative to home (needs homed).
Mode = CmdMode


class Fault(IntEnum):
    """Latched servo faults; cleared by a Mode.OFF command."""

    NONE = 0
    FOLLOWING_ERROR = 1  # |target - position| above max_following_error_counts
    ENCODER_JUMP = 2  # a counter moved more than max_encoder_step_counts in one tick
    HOME_SWITCH_NOT_FOUND = 3  # homing travelled home_search_limit_counts without a switch edge


def robot_servo_fields(model) -> dict:
    """The fields of :class:`ServoParams` a robot file defines (gearing, home, gains, limits)."""
    m = model.gearing.joint_to_counts_matrix
    cpd = np.abs(np.diag(m))
    dirs = tuple(int(np.sign(d) * s) for d, s in zip(np.diag(m), model.home_search_dir))
    out = dict(
        joint_to_counts=joint_to_counts_tuple(model.gearing),
        encoder_bits=int(model.gearing.encoder_bits),
        home_switch_deg=tuple(float(x) for x in model.home_switch_deg),
        home_search_dir=dirs,
        max_speed_counts_per_tick=tuple(int(round(v * c / SERVO_HZ)) for v, c in zip(model.vmax_deg_s, cpd)),
        target_min_counts=tuple(int(x) for x in model.counts_min),
        target_max_counts=tuple(int(x) for x in model.counts_max),
    )
    g = model.servo_gains
    if g is not None:
        out.update(kp_dac_per_count=g.kp_dac_per_count, ki_dac_per_count_tick=g.ki_dac_per_count_tick,
                   kd_dac_per_count_per_tick=g.kd_dac_per_count_per_tick, integral_limit_dac=g.integral_limit_dac)
    return out


def _default(key: str):
    return lambda: robot_servo_fields(load_robot(DEFAULT_ROBOT))[key]


@dataclass(frozen=True)
class ServoParams:
    """Constants of :class:`droid.subunits.reis.servo.ServoCore`."""

    joint_to_counts: tuple[tuple[float, ...], ...] = field(default_factory=_default("joint_to_counts"))
    """M [counts per joint degree], counts = M @ q_deg (droid.kinematics.gearing)."""
    encoder_bits: int = field(default_factory=_default("encoder_bits"))
    servo_rate_hz: float = SERVO_HZ  # droid.subunits.reis.device (the droid-servo declaration)
    command_rate_hz: float = HEARTBEAT_HZ  # droid.brain.cell.device (the droid-heartbeat declaration)
    # thesis §4.1.4: 8 way-points per command ("500Hz/60Hz ~ 8"); DROID's ramps span
    # the exact command period (8 or 9 ticks, droid.subunits.reis.command_queue), and
    # queue_steps is the length of one braking-profile load
    queue_steps: int = 8

    # PID, per tick (§4.1.5.1): dac = kp*e + sum(ki*e) + kd*(e - e_prev), e in counts
    # the gains are the robot file's [servo] table
    kp_dac_per_count: Six = field(default_factory=_default("kp_dac_per_count"))
    ki_dac_per_count_tick: Six = field(default_factory=_default("ki_dac_per_count_tick"))
    kd_dac_per_count_per_tick: Six = field(default_factory=_default("kd_dac_per_count_per_tick"))
    integral_limit_dac: Six = field(default_factory=_default("integral_limit_dac"))
    dac_min_counts: int = -2048  # servo_cmd limits (anti-windup, §4.1.5.1)
    dac_max_counts: int = 2047

    # planner (§4.1.5.2) and limits
    # the robot file's [limits] vmax_deg_s at 500 Hz (V15: 100/100/100/200/200/250 deg/s)
    max_speed_counts_per_tick: SixInt = field(default_factory=_default("max_speed_counts_per_tick"))
    # JOG targets also change speed by at most this (NORMAL way-points are the
    # planner's business): 5e5 / 1e6 counts/s^2, 450 / 900 joint deg/s^2
    jog_accel_counts_per_tick2: Six = (2.0, 2.0, 2.0, 4.0, 4.0, 4.0)
    # home-relative target limits: the robot file's encoder limits (joint_to_act()'s J*_MIN/J*_MAX)
    target_min_counts: SixInt = field(default_factory=_default("target_min_counts"))
    target_max_counts: SixInt = field(default_factory=_default("target_max_counts"))

    # starved queue (§4.1.5.1): coast this many ticks at the commanded velocity
    # waiting for a late command, then brake at brake_decel to zero and hold.
    # 7 ticks (14 ms) rides through a 10 ms stall of the command stream (the
    # stream runs up to a tick ahead of the queue; host stalls measured here:
    # 2-7 ms, some 10 ms under load -- docs/benchmarks.md, issue 16)
    starve_grace_ticks: int = 7
    brake_decel_counts_per_tick2: Six = (2.0, 2.0, 2.0, 4.0, 4.0, 4.0)  # 5e5 / 1e6 counts/s^2
    # after the brake has stopped the arm, a NORMAL way-point farther than this from where the
    # arm stands is not a resume but a stale target (the planner has not re-anchored): the
    # servo agent does not send it, and the servo refuses it (DROID addition: a way-point left
    # over from before a stall must never start the arm at full ramp speed from rest)
    resume_window_counts: int = 20

    # supervision
    max_following_error_counts: Six = (4000.0, 4000.0, 4000.0, 4000.0, 4000.0, 4000.0)
    max_encoder_step_counts: int = 3000  # per tick; more is a glitch (or a counter reset)

    # homing (§4.1.5.3)
    home_order: tuple[int, ...] = (5, 4, 3, 2, 1, 0)  # wrist first, 0-based joints
    # the robot file's [home]: known switch positions [deg] (plus any calibration offsets,
    # droid-calibrate), and the count direction that activates each switch
    home_switch_deg: Six = field(default_factory=_default("home_switch_deg"))
    home_search_dir: tuple[int, ...] = field(default_factory=_default("home_search_dir"))
    home_speed_counts_per_tick: int = 20  # "moderate speed"
    home_settle_ticks: int = 250  # rest after the switch is found, before the fine approach: 0.5 s, so the
    # links stop ringing on the compliant drives (~10 Hz, ~10 % damping: 0.2 s left ~30 % of it)
    home_fine_counts_per_tick: int = 1  # the final single-count approach
    # the edge at rest (DROID addition, issue 13): the fine approach catches the switch edge while
    # the motor stick-slips and the link rings on its drive, so the motor-side snapshot carries up
    # to ~0.02 deg of dynamic deflection (docs/reis.md); the edge is then bracketed by probes at
    # rest -- the link, frictionless on its drive, rests at its static deflection -- to
    # home_probe_resolution_counts, starting +-home_probe_counts around the caught edge
    home_probe_counts: int = 32  # 0.024-0.029 deg: beyond the largest dynamic error seen (0.022 deg); wider when needed
    home_probe_resolution_counts: int = 2  # the bracket's final width; the edge is its middle (+-1 count)
    home_probe_settle_ticks: int = 250  # 0.5 s per probe, as home_settle_ticks: joint 2's link (~7 Hz, ~10 % damped: decay time 0.22 s) rests
    home_probe_max: int = 16  # probes per joint before the bracket's middle is taken as it is
    home_search_limit_counts: int = 400_000  # ~360 joint degrees per phase

    def __post_init__(self) -> None:
        m = np.asarray(self.joint_to_counts, float)
        if m.shape != (6, 6) or not np.all(np.isfinite(m)) or abs(np.linalg.det(m)) < 1e-9:
            raise ValueError("joint_to_counts must be an invertible 6x6 matrix")
        if sorted(self.home_order) != list(range(6)):
            raise ValueError("home_order must list each joint 0..5 once")
        if self.queue_steps < 1:
            raise ValueError("need queue_steps >= 1")
        if self.servo_rate_hz <= 0 or self.command_rate_hz <= 0 or self.command_rate_hz > self.servo_rate_hz:
            raise ValueError("need 0 < command_rate_hz <= servo_rate_hz")
        if not 0 <= self.starve_grace_ticks < self.queue_steps:
            raise ValueError("need 0 <= starve_grace_ticks < queue_steps")
        if any(d not in (-1, 1) for d in self.home_search_dir):
            raise ValueError("home_search_dir entries must be +1 or -1")
        if self.home_probe_resolution_counts < 0 or self.home_probe_counts < 1 or self.home_probe_settle_ticks < 1 \
                or self.home_probe_max < 1:
            raise ValueError("need home_probe_resolution_counts >= 0 (0: off) and home_probe_counts, "
                             "home_probe_settle_ticks, home_probe_max >= 1")
        if any(lo >= hi for lo, hi in zip(self.target_min_counts, self.target_max_counts)):
            raise ValueError("target_min_counts must be below target_max_counts")

    @property
    def servo_period_s(self) -> float:
        return 1.0 / self.servo_rate_hz

    @classmethod
    def from_robot(cls, robot, home_offset_deg=None, **overrides) -> "ServoParams":
        """The servo of an arm: a bundled robot name, a ``.toml`` path or a RobotModel
        (raises :class:`droid.kinematics.RobotFileError` for a bad file).  ``home_offset_deg``
        (6, from droid-calibrate) is added to the robot file's switch positions: the switches'
        calibrated positions, which homing uses."""
        model = load_robot(robot) if isinstance(robot, (str, Path)) else robot
        fields = robot_servo_fields(model)
        if home_offset_deg is not None:
            off = np.asarray(home_offset_deg, float)
            if off.shape != (6,) or not np.all(np.isfinite(off)):
                raise ValueError("home_offset_deg: expected 6 finite numbers")
            fields["home_switch_deg"] = tuple(float(a + b) for a, b in zip(fields["home_switch_deg"], off))
        return cls(**{**fields, **overrides})

    @classmethod
    def for_robot_file(cls, path: str | Path, **overrides) -> "ServoParams":
        """Defaults with the gearing (and search directions) of a robot data file (gearing only:
        for files without the other tables; :meth:`from_robot` reads everything)."""
        gearing = load_gearing(path)
        dirs = tuple(int(np.sign(d)) for d in np.diag(gearing.joint_to_counts_matrix))
        return replace(cls(), joint_to_counts=joint_to_counts_tuple(gearing), home_search_dir=dirs, **overrides)
