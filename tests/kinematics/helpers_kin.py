"""Shared helpers for the kinematics tests: an independent D-H product (thesis eq. 4.1)."""
from __future__ import annotations

import math

import numpy as np

# Thesis Table 4.1 (Reis Robotstar V15), written out again here on purpose:
# theta_i = q_i + offset_i, standard D-H A_i = Rz(theta) Tz(d) Tx(a) Rx(alpha).
REIS_TABLE = [  # (theta offset deg, d mm, a mm, alpha deg)
    (0.0, 725.0, 0.0, 90.0),
    (90.0, 0.0, 600.0, 0.0),
    (0.0, 0.0, 0.0, 90.0),
    (0.0, 540.0, 0.0, -90.0),
    (0.0, 0.0, 0.0, 90.0),
    (0.0, 0.0, 0.0, 0.0),
]


def a_matrix(theta_deg: float, d: float, a: float, alpha_deg: float) -> np.ndarray:
    th, al = math.radians(theta_deg), math.radians(alpha_deg)
    ct, st, ca, sa = math.cos(th), math.sin(th), math.cos(al), math.sin(al)
    return np.array(
        [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1.0]]
    )


def dh_product(table, q_deg) -> np.ndarray:
    t = np.eye(4)
    for (off, d, a, alpha), q in zip(table, q_deg):
        t = t @ a_matrix(q + off, d, a, alpha)
    return t


def angle_diff_deg(a, b):
    """Smallest signed difference a - b [deg], elementwise."""
    return (np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0


def offset_robot_toml(name: str = "offset_test") -> str:
    """A robot of the OPW class with every offset non-zero (a data file only)."""
    a1, a2, b, c1, c2, c3, c4 = 150.0, -120.0, 80.0, 650.0, 700.0, 800.0, 100.0
    return f"""
name = "{name}"
description = "synthetic arm with shoulder, elbow, lateral and flange offsets"
assumed = true

[dh]
theta_offset_deg = [0, 90, 0, 0, 0, 0]
d_mm = [{c1}, {-b}, 0, {c3}, 0, {c4}]
a_mm = [{a1}, {c2}, {-a2}, 0, 0, 0]
alpha_deg = [90, 0, 90, -90, 90, 0]

[opw]
a1_mm = {a1}
a2_mm = {a2}
b_mm = {b}
c1_mm = {c1}
c2_mm = {c2}
c3_mm = {c3}
c4_mm = {c4}
offsets_deg = [0, 0, -90, -180, 0, 0]
signs = [1, -1, -1, 1, 1, 1]

[gearing]
reduction = [100, 100, 80, 50, 50, 40]
encoder_counts_per_rev = 2048
direction = [1, -1, 1, 1, -1, 1]
coupling = [
  [0, 0, 0, 0, 0, 0],
  [0, 0, 0, 0, 0, 0],
  [0, 0, 0, 0, 0, 0],
  [0, 0, 0, 0, 0, 0],
  [0, 0, 0, 0.02, 0, 0],
  [0, 0, 0, 0.01, 0.01, 0],
]
encoder_bits = 16

[limits]
joint_min_deg = [-170, -100, -120, -180, -130, -180]
joint_max_deg = [170, 100, 160, 180, 130, 180]
vmax_deg_s = [150, 150, 150, 300, 300, 400]

[home]
switch_deg = [0, 0, 0, 0, 0, 0]

[planner]
weights = [3, 3, 3, 1, 1, 1]
"""
