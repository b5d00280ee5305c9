"""ZeroMQ wire formats: one module of constants and (un)packers (after the ZeroMQ guide's patterns).

Heartbeat tick (PUB/SUB, one 40-byte frame, also used by agents to relay the
tick to their local programs)::

    <4s H H Q q q I I   magic b"DHB1", version, flags, tick, t_mono_ns,
                        period_ns, missed (ticks skipped so far), reserved

Brain <-> agent link (DEALER -> ROUTER, one exchange per tick; thesis §3.2
"at the start of each new cycle, command data is sent to each subunit, and each
subunit replies with its status data")::

    [LINK_PROTO, b"CMD", tick u64 LE, command record bytes | b""]
    [LINK_PROTO, b"STA", tick u64 LE, status record bytes]

Records carry their own header (magic, kind, version), checked on receipt.
Anything malformed is dropped and counted, never raised into a loop.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

HB_MAGIC = b"DHB1"
HB_VERSION = 1
_HB = struct.Struct("<4sHHQqqII")
HB_SIZE = _HB.size

LINK_PROTO = b"DROID-LINK/1"
KIND_CMD = b"CMD"
KIND_STA = b"STA"
_TICK = struct.Struct("<Q")

# Liveness (zguide Paranoid Pirate), counted in heartbeat ticks (droid.brain.plumbing.link)
LIVENESS_TICKS = 3  # missed ticks before a peer is declared stale (the cell file's stale_ticks default)
MAX_BACKOFF_TICKS = 120  # a remote's reconnect back-off doubles from LIVENESS_TICKS up to this


class BadFrame(ValueError):
    """A ZeroMQ message that does not follow the wire format."""


@dataclass(frozen=True)
class Tick:
    """One heartbeat: tick number, CLOCK_MONOTONIC timestamp [ns], period [ns]."""

    tick: int
    t_ns: int
    period_ns: int
    missed: int = 0


def pack_tick(t: Tick) -> bytes:
    return _HB.pack(HB_MAGIC, HB_VERSION, 0, t.tick, t.t_ns, t.period_ns, t.missed, 0)


def unpack_tick(frame: bytes) -> Tick:
    if len(frame) != HB_SIZE:
        raise BadFrame(f"heartbeat frame of {len(frame)} bytes, expected {HB_SIZE}")
    magic, ver, _flags, tick, t_ns, period_ns, missed, _ = _HB.unpack(frame)
    if magic != HB_MAGIC or ver != HB_VERSION:
        raise BadFrame(f"heartbeat frame with magic {magic!r} version {ver}")
    return Tick(tick, t_ns, period_ns, missed)


def pack_link(kind: bytes, tick: int, payload: bytes) -> list[bytes]:
    return [LINK_PROTO, kind, _TICK.pack(tick), payload]


def unpack_link(frames: list[bytes], expect_kind: bytes) -> tuple[int, bytes]:
    """Validate a link message; returns (tick, payload)."""
    if len(frames) != 4:
        raise BadFrame(f"link message of {len(frames)} frames, expected 4")
    proto, kind, tick, payload = frames
    if proto != LINK_PROTO:
        raise BadFrame(f"link protocol {proto[:20]!r}, expected {LINK_PROTO!r}")
    if kind != expect_kind:
        raise BadFrame(f"link message kind {kind[:8]!r}, expected {expect_kind!r}")
    if len(tick) != _TICK.size:
        raise BadFrame("link tick frame is not 8 bytes")
    return _TICK.unpack(tick)[0], payload
