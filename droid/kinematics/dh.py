"""Denavit–Hartenberg forward kinematics (thesis §4.1.1.1, Table 4.1, eq. 4.1–4.2).

Standard D-H: each link's A-matrix is ``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` with
``theta = q + theta_offset``; the wrist-centre pose is the product of the six
(eq. 4.2, without the world-to-base matrix 0A1, which is the model's base).

Note on the thesis: the printed 4A5 (eq. 4.1 D) has the row signs of a +90°
twist in its first two rows and of a -90° twist in its third, which is not a
rotation (determinant -1).  Table 4.1's twist of -90° for link 4 is the
consistent reading, and it is what the thesis's cart_to_joint() listing
inverts; the bundled Reis file uses the table.

The D-H product is the reference the loader checks each robot file's OPW
parameters against; the fast paths are in :mod:`droid.kinematics.opw`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DhTable:
    """Standard D-H table of a 6R arm: offsets and twists [deg], lengths [mm]."""

    theta_offset_deg: tuple
    d_mm: tuple
    a_mm: tuple
    alpha_deg: tuple

    def __post_init__(self) -> None:
        for name in ("theta_offset_deg", "d_mm", "a_mm", "alpha_deg"):
            vals = tuple(float(v) for v in getattr(self, name))
            if len(vals) != 6 or not all(math.isfinite(v) for v in vals):
                raise ValueError(f"dh: {name} must be 6 finite numbers")
            object.__setattr__(self, name, vals)


def link_matrix(theta_rad: float, d_mm: float, a_mm: float, alpha_rad: float) -> np.ndarray:
    """One standard D-H A-matrix Rz(theta) Tz(d) Tx(a) Rx(alpha) (eq. 4.1), 4x4."""
    ct, st = math.cos(theta_rad), math.sin(theta_rad)
    ca, sa = math.cos(alpha_rad), math.sin(alpha_rad)
    return np.array(
        [
            [ct, -st * ca, st * sa, a_mm * ct],
            [st, ct * ca, -ct * sa, a_mm * st],
            [0.0, sa, ca, d_mm],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def fk_dh(table: DhTable, q_deg) -> np.ndarray:
    """Wrist-centre pose (4x4, mm) of joint angles [deg] as the product of the six A-matrices."""
    t = np.eye(4)
    for q, off, d, a, alpha in zip(q_deg, table.theta_offset_deg, table.d_mm, table.a_mm, table.alpha_deg):
        t = t @ link_matrix(math.radians(float(q) + off), d, a, math.radians(alpha))
    return t
