"""The Reis's static drive deflection, from its robot file (plus mode on the full arm).

The Reis's encoders sit on the motor side of its 100:1 harmonic drives (thesis
§2.3, Table 4.1): the Status pose is the forward kinematics of the *motor*
angles, while the links sag by the drives' torsional compliance under the
static load (gravity minus the link-2 balancer).  Both the lead sensor and the
tool hang on link 6, so a constant deflection cancels in a seam tracker; what
does not cancel is its *change* between the configuration in which the lead
sensor saw a seam point and the one in which the tool reaches it, 100 mm later
(CAMERA_TO_TCP): on the R200 ramp the deflection at the tool point changes by
about 1 mm over the arc, and plus mode's tool missed the seam by 0.3-0.5 mm
there (docs/seamtrack.md, "On the full arm").

:class:`StaticDeflection` estimates the link angles from the motor angles,
``q_link = q_motor + K^-1 tau(q)``, with ``tau`` the torque gravity and the
balancer exert (the robot file's ``[dynamics]``: link masses and centres of
mass in their D-H frames, ``balancer_moment_nm``, ``hd_stiffness_nm_per_rad``),
one fixed-point step (the deflection is < 0.3 deg) -- *relative to the homing
pose*: the home switches are cams on the links (§4.1.5.3), so homing sets the
motor-side counts with the links deflected by the load at the switch pose
(``[home] switch_deg``), and the Status is off the links by the *change* of the
deflection since then, ``K^-1 (tau(q) - tau(q_home))``.  (In a full-arm R200
trial at rest: Status minus true tool point (-0.6, -0.17, 0.1..0.28) mm; this
model (-0.53, -0.15, 0.27) mm; the absolute deflection would be 2.4 mm.)
A robot file without ``[dynamics]`` gives no correction.  Units: mm, deg; N m.
"""
from __future__ import annotations

import math

import numpy as np

from droid.kinematics import RobotModel


def _rz(th: float) -> np.ndarray:
    c, s = math.cos(th), math.sin(th)
    T = np.eye(4)
    T[0, 0], T[0, 1], T[1, 0], T[1, 1] = c, -s, s, c
    return T


def _link(d_mm: float, a_mm: float, alpha_deg: float) -> np.ndarray:
    """Tz(d) Tx(a) Rx(alpha): from joint i's moving frame to D-H frame i [mm]."""
    al = math.radians(alpha_deg)
    c, s = math.cos(al), math.sin(al)
    return np.array([[1.0, 0.0, 0.0, a_mm], [0.0, c, -s, 0.0], [0.0, s, c, d_mm], [0.0, 0.0, 0.0, 1.0]])


class StaticDeflection:
    """Link angles from motor angles under the static load (see the module docstring)."""

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        dyn, dh = getattr(model, "dynamics", None), getattr(model, "dh", None)
        self.active = dyn is not None and dh is not None
        if not self.active:
            return
        self.links = [_link(dh.d_mm[i], dh.a_mm[i], dh.alpha_deg[i]) for i in range(6)]
        self.theta0 = np.radians(np.asarray(dh.theta_offset_deg, float))
        self.mass = np.asarray(dyn.link_mass_kg, float)
        self.com = np.asarray(dyn.link_com_mm, float)
        self.g = float(dyn.gravity_mps2)
        self.balancer = float(dyn.balancer_moment_nm)
        self.k = np.asarray(dyn.hd_stiffness_nm_per_rad, float)
        self.base = np.asarray(model.base, float)
        home = getattr(model, "home_switch_deg", None)
        self.tau_home = self.torque_nm(home) if home is not None else np.zeros(6)

    def torque_nm(self, q_deg) -> np.ndarray:
        """Joint torques [N m] gravity and the balancer exert at ``q_deg`` (+: drives the joint +)."""
        q = np.radians(np.asarray(q_deg, float))
        T = self.base @ _rz(self.theta0[0])
        axes, origins, coms = [], [], []
        for i in range(6):
            J = T @ _rz(q[i])  # joint i's moving frame
            axes.append(J[:3, 2].copy())
            origins.append(J[:3, 3].copy())
            D = J @ self.links[i]  # D-H frame i
            coms.append((D @ np.append(self.com[i], 1.0))[:3])
            if i < 5:
                T = D @ _rz(self.theta0[i + 1])
        f = np.array([0.0, 0.0, -self.g])  # per kg, the global frame (z up)
        tau = np.zeros(6)
        for j in range(6):
            for i in range(j, 6):
                r_m = (coms[i] - origins[j]) / 1000.0
                tau[j] += float(np.cross(axes[j], r_m) @ (self.mass[i] * f))
        tau[1] -= self.balancer * math.sin(q[1])  # the balancer holds link 2 up
        return tau

    def link_deg(self, q_motor_deg) -> np.ndarray:
        """The link angles [deg] of the motor angles ``q_motor_deg`` (the Status's joints)."""
        q = np.asarray(q_motor_deg, float)
        if not self.active:
            return q.copy()
        return q + np.degrees((self.torque_nm(q) - self.tau_home) / self.k)

    def motor_deg(self, q_link_deg) -> np.ndarray:
        """The motor angles [deg] that hold the links at ``q_link_deg`` (one fixed-point step)."""
        q = np.asarray(q_link_deg, float)
        if not self.active:
            return q.copy()
        m = q - np.degrees((self.torque_nm(q) - self.tau_home) / self.k)
        return q - np.degrees((self.torque_nm(m) - self.tau_home) / self.k)
