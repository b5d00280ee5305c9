"""Joint angles <-> motor encoder counts, including joint coupling (thesis §4.1.1.3).

Eq. 4.10 prints ``1000*4000/360`` while the text says the harmonic drives
reduce 100:1 and the motor encoders give 4000 counts a revolution; we read the
text: ``counts_per_deg = reduction * encoder_counts_per_rev / 360`` (for the
Reis 100 * 4000 / 360 = 1111.1 counts per joint degree).  The name "radians
to encoders" in eq. 4.10 is also a misnomer: the listing multiplies degrees.

The thesis gives the coupling as sequential assignments (eq. 4.11–4.14), e.g.
``j2 = j2_angle*G + j3/100`` and ``j3 = j3_angle*G + j2/100``, which read in
order are ambiguous (which j3 does eq. 4.11 use?).  We read them as one
simultaneous linear system::

    m = B q + C m        =>   m = (I - C)^-1 B q  =  M q
    q = B^-1 (I - C) m  =  M^-1 m

where ``q`` are joint angles [deg], ``m`` motor encoder counts relative to
home [counts], ``B = diag(direction) * counts_per_deg`` and ``C`` the coupling
matrix from the robot's data file.  Both maps are explicit matrices, so the
round trip is exact up to floating point.  (joint_to_act() evaluates the
assignments in sequence; that differs from the simultaneous reading by a
relative 1e-4, i.e. 0.01 deg at 100 deg — see docs/kinematics.md.)

The hardware counters are 16 bits (Reis VME cards; 24 bits on the CIO-QUAD04
cards of the Fanuc); :func:`extend_counter` turns successive raw readings into
an unbounded signed count (the servo's roll-over handling, thesis §4.1.5.1).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


def _bits(value) -> int:
    """A robot file's ``encoder_bits``: an integer (its range, 2..62, is checked by Gearing)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"gearing: encoder_bits must be an integer in 2..62, got {value!r}")
    return int(value)


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class Gearing:
    """Linear joint [deg] <-> motor-count [counts] maps for a 6-axis arm."""

    counts_per_deg: np.ndarray  # (6,) motor counts per joint degree (unsigned)
    direction: np.ndarray  # (6,) +1/-1
    coupling: np.ndarray  # (6, 6)
    encoder_bits: int = 16
    encoder_counts_per_rev: object = 4000.0  # (6,) motor encoder counts per motor revolution

    @property
    def reduction(self) -> np.ndarray:
        """Gear ratios (motor revolutions per joint revolution), (6,)."""
        return self.counts_per_deg * 360.0 / self.encoder_counts_per_rev

    def __post_init__(self) -> None:
        cpd = np.asarray(self.counts_per_deg, float)
        direc = np.asarray(self.direction, float)
        coup = np.asarray(self.coupling, float)
        if cpd.shape != (6,) or not np.all(np.isfinite(cpd)) or np.any(cpd <= 0):
            raise ValueError("gearing: counts_per_deg must be 6 finite numbers > 0")
        if direc.shape != (6,) or not np.all(np.isin(direc, (-1.0, 1.0))):
            raise ValueError("gearing: direction must be 6 entries of +1 or -1")
        if coup.shape != (6, 6) or not np.all(np.isfinite(coup)):
            raise ValueError("gearing: coupling must be a finite 6x6 matrix")
        if abs(np.linalg.det(np.eye(6) - coup)) < 1e-9:
            raise ValueError("gearing: I - coupling is singular (coupling cannot be solved)")
        if not 2 <= int(self.encoder_bits) <= 62:
            raise ValueError("gearing: encoder_bits must be in 2..62")
        object.__setattr__(self, "counts_per_deg", _readonly(cpd.copy()))
        object.__setattr__(self, "direction", _readonly(direc.copy()))
        object.__setattr__(self, "coupling", _readonly(coup.copy()))
        object.__setattr__(self, "encoder_bits", int(self.encoder_bits))
        cpr = np.broadcast_to(np.asarray(self.encoder_counts_per_rev, float), (6,)).copy()
        if not np.all(np.isfinite(cpr)) or np.any(cpr <= 0):
            raise ValueError("gearing: encoder_counts_per_rev must be > 0")
        object.__setattr__(self, "encoder_counts_per_rev", _readonly(cpr))

    @classmethod
    def from_table(cls, table: dict) -> "Gearing":
        """Build from a robot file's ``[gearing]`` table.

        Keys: ``reduction`` and ``encoder_counts_per_rev`` (a number or 6),
        optional ``direction`` (6 of +1/-1), ``coupling`` (6x6), ``encoder_bits``.
        """
        try:
            reduction = np.broadcast_to(np.asarray(table["reduction"], float), (6,))
            cpr = np.broadcast_to(np.asarray(table["encoder_counts_per_rev"], float), (6,))
        except KeyError as exc:
            raise ValueError(f"gearing: missing key {exc.args[0]!r}") from None
        except (ValueError, TypeError):
            raise ValueError("gearing: reduction and encoder_counts_per_rev must be a number or 6 numbers") from None
        try:
            direction = np.asarray(table.get("direction", [1] * 6), float)
            coupling = np.asarray(table.get("coupling", np.zeros((6, 6))), float)
        except (ValueError, TypeError):
            raise ValueError("gearing: direction must be 6 numbers and coupling a 6x6 matrix") from None
        if np.any(reduction <= 0) or np.any(cpr <= 0):
            raise ValueError("gearing: reduction and encoder_counts_per_rev must be > 0")
        return cls(
            counts_per_deg=np.array(reduction * cpr / 360.0),
            direction=direction,
            coupling=coupling,
            encoder_bits=_bits(table.get("encoder_bits", 16)),
            encoder_counts_per_rev=cpr,
        )

    @cached_property
    def joint_to_counts_matrix(self) -> np.ndarray:
        """M such that counts = M @ q_deg (read-only)."""
        b = np.diag(self.direction * self.counts_per_deg)
        return _readonly(np.linalg.solve(np.eye(6) - self.coupling, b))

    @cached_property
    def counts_to_joint_matrix(self) -> np.ndarray:
        """M^-1 such that q_deg = M^-1 @ counts (exact inverse of the above, read-only)."""
        binv = np.diag(1.0 / (self.direction * self.counts_per_deg))
        return _readonly(binv @ (np.eye(6) - self.coupling))

    @cached_property
    def sparse_rows(self) -> tuple:
        """Rows of M as tuples of (joint index, counts per deg), zeros dropped (fast scalar path)."""
        m = self.joint_to_counts_matrix
        return tuple(tuple((j, float(m[i, j])) for j in range(6) if m[i, j] != 0.0) for i in range(6))

    def joints_to_counts(self, q_deg) -> np.ndarray:
        """Joint angles [deg] (..., 6) -> motor counts [counts, float] (..., 6)."""
        return np.asarray(q_deg, float) @ self.joint_to_counts_matrix.T

    def counts_to_joints(self, counts) -> np.ndarray:
        """Motor counts [counts] (..., 6) -> joint angles [deg] (..., 6)."""
        return np.asarray(counts, float) @ self.counts_to_joint_matrix.T

    def joints_to_counts_int(self, q_deg) -> np.ndarray:
        """Joint angles [deg] (..., 6) -> motor counts rounded to the nearest integer [counts] (int64)."""
        return np.rint(self.joints_to_counts(q_deg)).astype(np.int64)


def extend_counter(previous_extended: int, raw: int, bits: int = 16) -> int:
    """Extend a wrapping ``bits``-wide hardware counter reading to an unbounded count.

    ``previous_extended`` is the last extended value [counts]; ``raw`` the new
    register value (0 .. 2**bits-1).  Assumes the counter moved less than half
    its range since the last reading (at 500 Hz that is 32767 counts per 2 ms).
    A move of exactly half the range is read as backwards.
    """
    span = 1 << bits
    delta = (raw - previous_extended) % span
    if delta >= span // 2:
        delta -= span
    return previous_extended + delta


def extend_counters(previous_extended, raw, bits: int = 16) -> np.ndarray:
    """Vector form of :func:`extend_counter` for int arrays (e.g. 6 joints) [counts] -> int64."""
    prev = np.asarray(previous_extended, np.int64)
    span = np.int64(1) << np.int64(bits)
    delta = np.mod(np.asarray(raw, np.int64) - prev, span)
    delta = np.where(delta >= span // 2, delta - span, delta)
    return prev + delta
