"""Joint angles <-> motor encoder counts, including joint coupling (thesis §4.1.1.3).

The thesis gives the coupling as sequential assignments (eq. 4.11–4.14), e.g.
``j2 = j2_angle*G + j3/100`` and ``j3 = j3_angle*G + j2/100``, which read in
order are ambiguous (which j3 does eq. 4.11 use?).  We read them as one
simultaneous linear system::

    m = B q + C m        =>   m = (I - C)^-1 B q  =  M q
    q = B^-1 (I - C) m  =  M^-1 m

where ``q`` are joint angles [deg], ``m`` motor encoder counts relative to
home [counts], ``B = diag(direction) * counts_per_deg`` and ``C`` the coupling
matrix from the robot's data file.  Both maps are explicit matrices, so the
round trip is exact up to floating point.

The hardware counters are 16 bits; :func:`extend_counter` turns successive raw
readings into an unbounded signed count (the servo's roll-over handling,
thesis §4.1.5.1).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Gearing:
    """Linear joint <-> motor-count maps for a 6-axis arm."""

    counts_per_deg: np.ndarray  # (6,) motor counts per joint degree (unsigned)
    direction: np.ndarray  # (6,) +1/-1
    coupling: np.ndarray  # (6, 6)
    encoder_bits: int = 16

    @classmethod
    def from_table(cls, table: dict) -> "Gearing":
        """Build from a robot file's ``[gearing]`` table."""
        reduction = np.broadcast_to(np.asarray(table["reduction"], float), (6,))
        cpr = np.broadcast_to(np.asarray(table["encoder_counts_per_rev"], float), (6,))
        direction = np.asarray(table.get("direction", [1] * 6), float)
        coupling = np.asarray(table.get("coupling", np.zeros((6, 6))), float)
        if direction.shape != (6,) or coupling.shape != (6, 6):
            raise ValueError("gearing: direction must have 6 entries and coupling be 6x6")
        return cls(
            counts_per_deg=np.array(reduction * cpr / 360.0),
            direction=direction,
            coupling=coupling,
            encoder_bits=int(table.get("encoder_bits", 16)),
        )

    @property
    def joint_to_counts_matrix(self) -> np.ndarray:
        """M such that counts = M @ q_deg."""
        b = np.diag(self.direction * self.counts_per_deg)
        return np.linalg.solve(np.eye(6) - self.coupling, b)

    @property
    def counts_to_joint_matrix(self) -> np.ndarray:
        """M^-1 such that q_deg = M^-1 @ counts (exact inverse of the above)."""
        binv = np.diag(1.0 / (self.direction * self.counts_per_deg))
        return binv @ (np.eye(6) - self.coupling)

    def joints_to_counts(self, q_deg) -> np.ndarray:
        """Joint angles [deg] (..., 6) -> motor counts [counts, float] (..., 6)."""
        return np.asarray(q_deg, float) @ self.joint_to_counts_matrix.T

    def counts_to_joints(self, counts) -> np.ndarray:
        """Motor counts [counts] (..., 6) -> joint angles [deg] (..., 6)."""
        return np.asarray(counts, float) @ self.counts_to_joint_matrix.T


def extend_counter(previous_extended: int, raw: int, bits: int = 16) -> int:
    """Extend a wrapping ``bits``-wide hardware counter reading to an unbounded count.

    ``previous_extended`` is the last extended value [counts]; ``raw`` the new
    register value (0 .. 2**bits-1).  Assumes the counter moved less than half
    its range since the last reading (at 500 Hz that is 32767 counts per 2 ms).
    """
    span = 1 << bits
    delta = (raw - previous_extended) % span
    if delta >= span // 2:
        delta -= span
    return previous_extended + delta
