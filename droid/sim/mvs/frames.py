"""Small 4x4 homogeneous-transform helpers for the MVS twin (mm, rad).

Local to droid/sim on purpose: the lead will later unify these with
droid.kinematics.  Every transform is a (4, 4) float array ``T_A_B`` mapping
points in frame B to frame A (``p_A = T_A_B @ p_B``).
"""
from __future__ import annotations

import math

import numpy as np


def rot_x(angle_rad: float) -> np.ndarray:
    """Rotation about x by ``angle_rad`` (right-handed), as a 4x4."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    t = np.eye(4)
    t[1:3, 1:3] = [[c, -s], [s, c]]
    return t


def rot_y(angle_rad: float) -> np.ndarray:
    """Rotation about y by ``angle_rad`` (right-handed), as a 4x4."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    t = np.eye(4)
    t[0, 0], t[0, 2], t[2, 0], t[2, 2] = c, s, -s, c
    return t


def rot_z(angle_rad: float) -> np.ndarray:
    """Rotation about z by ``angle_rad`` (right-handed), as a 4x4."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    t = np.eye(4)
    t[0:2, 0:2] = [[c, -s], [s, c]]
    return t


def translation(x_mm: float, y_mm: float, z_mm: float) -> np.ndarray:
    """Pure translation by (x, y, z) mm, as a 4x4."""
    t = np.eye(4)
    t[0:3, 3] = (x_mm, y_mm, z_mm)
    return t


def invert(t: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform (R^T, -R^T p)."""
    r = t[0:3, 0:3]
    out = np.eye(4)
    out[0:3, 0:3] = r.T
    out[0:3, 3] = -r.T @ t[0:3, 3]
    return out


def apply(t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map (N, 3) points (or one (3,) point) through the 4x4 ``t``."""
    p = np.asarray(points, float)
    return p @ t[0:3, 0:3].T + t[0:3, 3]
