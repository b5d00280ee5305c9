"""Homogeneous transforms and ZYZ Euler angles (thesis eq. 4.1, 4.2; mat_inv_homo of §5).

Pure numpy helpers used across the project.  Conventions:

* positions in mm, Euler angles in **degrees**, the elementary rotations
  :func:`rotx`, :func:`roty`, :func:`rotz` take **radians**;
* a pose is ``(x, y, z, a, b, c)``: position [mm] and Z-Y'-Z'' Euler angles
  [deg] of thesis eq. 4.2, ``R = Rz(a) @ Ry(b) @ Rz(c)``;
* :func:`R_to_zyz` returns ``b`` in [0, 180]; at ``b == 0`` or ``b == 180``
  (gimbal lock) it sets ``a = 0`` and puts the whole rotation into ``c``, as
  the thesis's cart_to_joint() does for the wrist (§4.1.7);
* every function that takes angles or poses broadcasts over leading
  dimensions (``pose_to_T`` of an (N, 6) array gives (N, 4, 4)).
"""
from __future__ import annotations

import math

import numpy as np

try:  # what np.einsum(optimize=False) calls, without its Python wrapper (a private name of numpy 2)
    from numpy._core.multiarray import c_einsum
except ImportError:  # numpy 1.x (pyproject allows >= 1.24): the public call, the same sums
    c_einsum = np.einsum

EYE4 = np.eye(4)  # copied where a fresh identity is filled in (np.eye's call costs more: issue 28 item 2)

DEG_PER_RAD = 180.0 / math.pi
RAD_PER_DEG = math.pi / 180.0

#: |sin b| below which R_to_zyz treats the Euler angles as gimbal-locked.
GIMBAL_EPS = 1e-12


def wrap_deg(angle_deg):
    """Wrap angles [deg] into (-180, 180].

    A scalar is wrapped exactly (IEEE remainder); arrays are wrapped with an
    absolute error below 1e-13 deg.
    """
    if np.ndim(angle_deg) == 0:
        w = math.remainder(float(angle_deg), 360.0)
        return 180.0 if w == -180.0 else w
    a = np.asarray(angle_deg, float)
    w = np.remainder(a + 180.0, 360.0) - 180.0  # [-180, 180)
    return np.where(w <= -180.0, 180.0, w)


def rotx(angle_rad: float) -> np.ndarray:
    """4x4 homogeneous rotation about x by ``angle_rad`` [rad]."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def roty(angle_rad: float) -> np.ndarray:
    """4x4 homogeneous rotation about y by ``angle_rad`` [rad]."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0, s, 0], [0, 1.0, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def rotz(angle_rad: float) -> np.ndarray:
    """4x4 homogeneous rotation about z by ``angle_rad`` [rad]."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])


def trans(x_mm: float, y_mm: float, z_mm: float) -> np.ndarray:
    """4x4 homogeneous translation by (x, y, z) [mm]."""
    t = np.eye(4)
    t[:3, 3] = (x_mm, y_mm, z_mm)
    return t


def zyz_to_R(a_deg, b_deg, c_deg) -> np.ndarray:
    """Rotation matrix Rz(a) Ry(b) Rz(c) of thesis eq. 4.2; angles [deg], broadcasts -> (..., 3, 3)."""
    a = np.asarray(a_deg, float) * RAD_PER_DEG
    b = np.asarray(b_deg, float) * RAD_PER_DEG
    c = np.asarray(c_deg, float) * RAD_PER_DEG
    a, b, c = np.broadcast_arrays(a, b, c)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    r = np.empty(a.shape + (3, 3))
    r[..., 0, 0] = ca * cb * cc - sa * sc
    r[..., 0, 1] = -ca * cb * sc - sa * cc
    r[..., 0, 2] = ca * sb
    r[..., 1, 0] = sa * cb * cc + ca * sc
    r[..., 1, 1] = -sa * cb * sc + ca * cc
    r[..., 1, 2] = sa * sb
    r[..., 2, 0] = -sb * cc
    r[..., 2, 1] = sb * sc
    r[..., 2, 2] = cb
    return r


def R_to_zyz(R) -> np.ndarray:
    """ZYZ Euler angles (a, b, c) [deg] of a rotation matrix (..., 3, 3) -> (..., 3).

    ``b`` is in [0, 180].  Gimbal lock (``sin b`` < :data:`GIMBAL_EPS`): ``b`` is
    snapped to 0 or 180, ``a = 0`` and ``c`` carries the whole rotation about z
    (thesis §4.1.7 policy).
    """
    r = np.asarray(R, float)
    r02, r12, r22 = r[..., 0, 2], r[..., 1, 2], r[..., 2, 2]
    sb = np.hypot(r02, r12)
    locked = sb < GIMBAL_EPS
    b = np.where(locked, np.where(r22 > 0, 0.0, np.pi), np.arctan2(sb, r22))
    a = np.where(locked, 0.0, np.arctan2(r12, r02))
    # c from the residual Rz(c) = Ry(-b) Rz(-a) R: exact for any a, robust near lock
    ca, sa, cb, sbb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    w = ca * r[..., 0, 0] + sa * r[..., 1, 0]
    m00 = cb * w - sbb * r[..., 2, 0]
    m10 = -sa * r[..., 0, 0] + ca * r[..., 1, 0]
    c = np.arctan2(m10, m00)
    out = np.stack([a, b, c], axis=-1) * DEG_PER_RAD
    return wrap_deg(out)


def pose_to_T(x_mm, y_mm, z_mm, a_deg, b_deg, c_deg) -> np.ndarray:
    """Homogeneous transform (..., 4, 4) of a pose: position [mm], ZYZ Euler angles [deg] (eq. 4.2)."""
    r = zyz_to_R(a_deg, b_deg, c_deg)
    x, y, z = np.broadcast_arrays(*(np.asarray(v, float) for v in (x_mm, y_mm, z_mm)))
    shape = np.broadcast_shapes(r.shape[:-2], x.shape)
    t = np.zeros(shape + (4, 4))
    t[..., :3, :3] = r
    t[..., 0, 3] = x
    t[..., 1, 3] = y
    t[..., 2, 3] = z
    t[..., 3, 3] = 1.0
    return t


def T_to_pose(T) -> np.ndarray:
    """Pose (x, y, z [mm], a, b, c [deg ZYZ]) of a transform (..., 4, 4) -> (..., 6)."""
    t = np.asarray(T, float)
    return np.concatenate([t[..., :3, 3], R_to_zyz(t[..., :3, :3])], axis=-1)


def inv_homo(T) -> np.ndarray:
    """Inverse of a rigid homogeneous transform (..., 4, 4): [R^T, -R^T p] (thesis mat_inv_homo)."""
    t = np.asarray(T, float)
    rt = np.swapaxes(t[..., :3, :3], -1, -2)
    out = np.zeros(t.shape)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -c_einsum("...ij,...j->...i", rt, t[..., :3, 3])  # np.einsum without its wrapper
    out[..., 3, 3] = 1.0
    return out


def is_rigid(T, tol: float = 1e-9) -> bool:
    """True if ``T`` is a 4x4 finite homogeneous transform with an orthonormal, right-handed rotation."""
    t = np.asarray(T, float)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        return False
    r = t[:3, :3]
    if not np.allclose(t[3], (0, 0, 0, 1), atol=tol, rtol=0):
        return False
    return bool(np.allclose(r @ r.T, np.eye(3), atol=tol, rtol=0) and np.linalg.det(r) > 0)


def record_pose(rec) -> np.ndarray:
    """A DROID record's wrist-centre pose (its ``R``, ``x``, ``y``, ``z`` fields: thesis Table 3.1,
    Status and Command alike) as a 4x4 homogeneous transform [mm]."""
    T = EYE4.copy()
    T[:3, :3] = rec["R"]
    T[:3, 3] = (float(rec["x"]), float(rec["y"]), float(rec["z"]))
    return T
