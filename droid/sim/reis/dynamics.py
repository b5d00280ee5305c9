"""Rigid-body model of a 6R arm from its robot file, with Pinocchio (thesis §2.3, Table 4.1).

Pinocchio (``import pinocchio as pin``; PyPI ``pin``) is the field's standard
rigid-body library (Featherstone's algorithms in C++): the plant twin
(:mod:`droid.sim.reis.plant`) asks it for the joint-space inverse mass matrix
``M(q)^-1`` (``computeMinverse``) and the bias torques ``C(q, qd) qd + g(q)``
(``nonLinearEffects``), which give the configuration-dependent inertia, the
coupling between joints and gravity.

The model is built from the robot file's standard D-H table (eq. 4.1,
``A_i = Rz(theta_off_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``) and its
``[dynamics]`` table (droid.kinematics.dynamics): joint *i* is a revolute
joint about the z axis of frame *i-1* (rotated by the offset), link *i*'s
centre of mass and inertia are given in D-H frame *i*.  Lengths are converted
to metres.  ``dh_error`` adds small length/twist errors (the world is not the
model, issue 13): the plant integrates the true arm while the controller plans
with the file's.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from droid.kinematics.dh import DhTable


@dataclass(frozen=True)
class DhError:
    """Differences of the true arm from its D-H table: lengths [mm], twists [deg] (6 each)."""

    d_mm: tuple = (0.0,) * 6
    a_mm: tuple = (0.0,) * 6
    alpha_deg: tuple = (0.0,) * 6

    def apply(self, dh: DhTable) -> DhTable:
        return DhTable(theta_offset_deg=dh.theta_offset_deg,
                       d_mm=tuple(a + b for a, b in zip(dh.d_mm, self.d_mm)),
                       a_mm=tuple(a + b for a, b in zip(dh.a_mm, self.a_mm)),
                       alpha_deg=tuple(a + b for a, b in zip(dh.alpha_deg, self.alpha_deg)))

    @property
    def zero(self) -> bool:
        return not any(self.d_mm) and not any(self.a_mm) and not any(self.alpha_deg)


def _link_transform(dh: DhTable, i: int) -> pin.SE3:
    """Tz(d_i) Tx(a_i) Rx(alpha_i) of link i (0-based) [m]: from joint i's moving frame to D-H frame i."""
    al = math.radians(dh.alpha_deg[i])
    c, s = math.cos(al), math.sin(al)
    R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    return pin.SE3(R, np.array([dh.a_mm[i], 0.0, dh.d_mm[i]]) / 1000.0)


def _rz(deg: float) -> pin.SE3:
    th = math.radians(deg)
    c, s = math.cos(th), math.sin(th)
    return pin.SE3(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.zeros(3))


def build_model(dh: DhTable, dynamics, base_T_mm=None) -> pin.Model:
    """A Pinocchio model of the arm: 6 revolute joints, link masses/COMs/inertias, gravity -z."""
    model = pin.Model()
    model.name = "arm"
    base = np.eye(4) if base_T_mm is None else np.asarray(base_T_mm, float)
    placement = pin.SE3(base[:3, :3].copy(), base[:3, 3] / 1000.0) * _rz(dh.theta_offset_deg[0])
    parent = 0
    for i in range(6):
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f"joint{i + 1}")
        L = _link_transform(dh, i)
        com = L.act(np.asarray(dynamics.link_com_mm[i], float) / 1000.0)
        inertia = L.rotation @ np.asarray(dynamics.link_inertia_kgm2[i], float) @ L.rotation.T
        model.appendBodyToJoint(jid, pin.Inertia(float(dynamics.link_mass_kg[i]), com, inertia), pin.SE3.Identity())
        if i < 5:
            placement = L * _rz(dh.theta_offset_deg[i + 1])
        parent = jid
    model.gravity.linear = np.array([0.0, 0.0, -float(dynamics.gravity_mps2)])
    return model


class RigidBody:
    """``M(q)^-1`` and ``C(q, qd) qd + g(q)`` of an arm [SI: rad, N m, kg m^2]."""

    def __init__(self, dh: DhTable, dynamics, base_T_mm=None) -> None:
        self.dh = dh
        self.model = build_model(dh, dynamics, base_T_mm)
        self.data = self.model.createData()
        self.link6 = _link_transform(dh, 5)  # link 6's D-H transform: joint 6's frame -> the wrist centre [m]
        n = self.model.nv
        self._upper = np.triu(np.ones((n, n), bool))  # Pinocchio fills the upper triangle of M and Minv

    def minv(self, q_rad: np.ndarray) -> np.ndarray:
        pin.computeMinverse(self.model, self.data, q_rad)
        mi = self.data.Minv
        return np.where(self._upper, mi, mi.T)  # Pinocchio fills the upper triangle

    def mass(self, q_rad: np.ndarray) -> np.ndarray:
        pin.crba(self.model, self.data, q_rad)
        m = self.data.M
        return np.where(self._upper, m, m.T)

    def bias(self, q_rad: np.ndarray, qd_rad_s: np.ndarray) -> np.ndarray:
        return pin.nonLinearEffects(self.model, self.data, q_rad, qd_rad_s).copy()

    def gravity(self, q_rad: np.ndarray) -> np.ndarray:
        return pin.computeGeneralizedGravity(self.model, self.data, q_rad).copy()

    def wcp_mm(self, q_deg) -> np.ndarray:
        """The wrist-centre pose (4x4, mm) of the model: joint 6's frame times link 6's transform."""
        pin.forwardKinematics(self.model, self.data, np.radians(np.asarray(q_deg, float)))
        M = self.data.oMi[6] * self.link6
        T = np.eye(4)
        T[:3, :3] = M.rotation
        T[:3, 3] = M.translation * 1000.0
        return T
