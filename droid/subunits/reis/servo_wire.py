"""Messages between droid-servo-agent, droid-servo and droid-watchdog (thesis §4.1.5–4.1.6).

"Message Passing is more suited for the servo program so as to avoid a lock up
if it were to access a shared memory area instead."  The servo never touches
a shared database: the servo agent sends it one command message per 60 Hz
period (ZeroMQ PUSH -> the servo's PULL), and the servo publishes its status
(PUB) every few servo ticks for the servo agent and the watchdog.

Command  ``<4s I i 6i``   b"DSC2", seq, mode (CmdMode), encoder command [counts]
Status   ``<4s Q i i i i i i i 6i 6i 6i 6h``
         b"DSS2", servo tick, mode (CmdMode), homed, homing joint (-1 none), starved,
         braking, fault, amplifiers powered, encoder_pos, encoder_cmd,
         following_error [counts], DACs
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

# Version 2: ``mode`` carries droid.brain.db.layouts.CmdMode's numbers (JOG 1, HOME 2; version 1
# numbered the servo's own HOME 1, JOG 2): a servo and agent of different versions refuse
# each other's messages (counted as bad frames, the servo brakes) instead of swapping modes.
CMD_MAGIC = b"DSC2"
STATUS_MAGIC = b"DSS2"
_CMD = struct.Struct("<4sIi6i")
_STATUS = struct.Struct("<4sQiiiiiii6i6i6i6h")
STATUS_EVERY_TICKS = 4  # the servo publishes at 500/4 = 125 Hz


class BadServoMessage(ValueError):
    pass


@dataclass(frozen=True)
class ServoCommand:
    seq: int
    mode: int  # droid.brain.db.layouts.CmdMode (= servo_params.Mode)
    counts: tuple[int, ...]


@dataclass(frozen=True)
class ServoReport:
    tick: int
    mode: int
    homed: bool
    homing_joint: int
    starved: bool
    braking: bool
    fault: int
    amps_on: bool
    encoder_pos: tuple[int, ...]
    encoder_cmd: tuple[int, ...]
    following_error: tuple[int, ...]
    dac: tuple[int, ...]


def pack_command(c: ServoCommand) -> bytes:
    return _CMD.pack(CMD_MAGIC, c.seq & 0xFFFFFFFF, int(c.mode), *[int(v) for v in c.counts])


def unpack_command(b: bytes) -> ServoCommand:
    if len(b) != _CMD.size:
        raise BadServoMessage(f"servo command of {len(b)} bytes, expected {_CMD.size}")
    magic, seq, mode, *counts = _CMD.unpack(b)
    if magic != CMD_MAGIC:
        raise BadServoMessage(f"servo command magic {magic!r}")
    return ServoCommand(seq, mode, tuple(counts))


def _clip32(v) -> int:
    return max(-(2**31), min(2**31 - 1, int(v)))


def pack_status(s, amps_on: bool = True) -> bytes:
    """``s``: a droid.subunits.reis.servo.ServoStatus; ``amps_on`` from the VME AMP_STATUS register."""
    lo, hi = -(2**31), 2**31 - 1  # _clip32 over the 18 counts (every 4th servo tick), when one is out
    counts = list(map(int, (*s.encoder_pos, *s.encoder_cmd, *s.following_error)))
    if min(counts) < lo or max(counts) > hi:
        counts = [min(hi, max(lo, v)) for v in counts]
    return _STATUS.pack(STATUS_MAGIC, s.tick, int(s.mode), int(s.homed), int(s.homing_joint),
                        int(s.starved), int(s.braking), int(s.fault), int(bool(amps_on)),
                        *counts, *map(int, s.dac))


def pack_status_values(tick: int, mode: int, homed: int, homing_joint: int, starved: int, braking: int,
                       fault: int, amps_on: int, counts: list, dac) -> bytes:
    """:func:`pack_status` of plain ints (droid.subunits.reis.servo.ServoCore.status_message):
    ``counts`` the 18 of encoder_pos, encoder_cmd and following_error, clipped here as there."""
    lo, hi = -(2**31), 2**31 - 1
    if min(counts) < lo or max(counts) > hi:
        counts = [min(hi, max(lo, v)) for v in counts]
    return _STATUS.pack(STATUS_MAGIC, tick, mode, homed, homing_joint, starved, braking, fault, amps_on,
                        *counts, *map(int, dac))


_last_status: list = [b"", None]  # the last message unpacked and its (frozen) report


def unpack_status(b: bytes) -> ServoReport:
    """A status message -> its :class:`ServoReport`.  The servo's watchdog and agent each unpack
    the same message: the last one's report (frozen, immutable) is handed out again."""
    if b == _last_status[0]:
        return _last_status[1]
    if len(b) != _STATUS.size:
        raise BadServoMessage(f"servo status of {len(b)} bytes, expected {_STATUS.size}")
    v = _STATUS.unpack(b)
    if v[0] != STATUS_MAGIC:
        raise BadServoMessage(f"servo status magic {v[0]!r}")
    rep = ServoReport(tick=v[1], mode=v[2], homed=bool(v[3]), homing_joint=v[4], starved=bool(v[5]),
                      braking=bool(v[6]), fault=v[7], amps_on=bool(v[8]), encoder_pos=v[9:15],
                      encoder_cmd=v[15:21], following_error=v[21:27], dac=v[27:33])
    _last_status[0], _last_status[1] = bytes(b), rep
    return rep
