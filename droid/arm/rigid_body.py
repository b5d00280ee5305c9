"""Rigid-body model of a 6R arm from its robot file: Pinocchio or the compiled kernel (thesis §2.3, Table 4.1).

Pinocchio (``import pinocchio as pin``; PyPI ``pin``) is the field's standard
rigid-body library (Featherstone's algorithms in C++): the plant twin
(:mod:`droid.sim.reis.plant`) asks it for the joint-space inverse mass matrix
``M(q)^-1`` (``computeMinverse``) and the bias torques ``C(q, qd) qd + g(q)``
(``nonLinearEffects``), which give the configuration-dependent inertia, the
coupling between joints and gravity.

:class:`RigidBody` has two backends, the same model and the same methods:

* ``"pinocchio"`` (the default): Pinocchio's calls, as every lockstep trial has made them
  since its tables were published (their results are bit for bit reproducible);
* ``"kernel"``: the compiled recursive Newton-Euler and composite-rigid-body algorithms of
  :mod:`droid._kernel` (``droid/_kernel.c``, ``rb_*``; ``M^-1`` and the forward dynamics by a
  Cholesky solve), which never imports Pinocchio (~48 MB resident with coal and eigenpy).
  droid-sim's world uses it (:func:`world_backend`).  It agrees with Pinocchio to rounding,
  not bit for bit (tests/sim/test_rigid_body_kernel.py states the tolerances).

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

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from droid.kinematics.dh import DhTable

#: the backends of :class:`RigidBody`
BACKENDS = ("pinocchio", "kernel")


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


class Placement(NamedTuple):
    """A rigid transform without Pinocchio: ``rotation`` (3x3) and ``translation`` (3,) [m]."""

    rotation: np.ndarray
    translation: np.ndarray


def _link_rt(dh: DhTable, i: int) -> Placement:
    """Tz(d_i) Tx(a_i) Rx(alpha_i) of link i (0-based) [m]: from joint i's moving frame to D-H frame i."""
    al = math.radians(dh.alpha_deg[i])
    c, s = math.cos(al), math.sin(al)
    R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    return Placement(R, np.array([dh.a_mm[i], 0.0, dh.d_mm[i]]) / 1000.0)


def _rz_rotation(deg: float) -> np.ndarray:
    th = math.radians(deg)
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _link_transform(dh: DhTable, i: int):
    """:func:`_link_rt` as a Pinocchio ``SE3``."""
    import pinocchio as pin

    return pin.SE3(*_link_rt(dh, i))


def _rz(deg: float):
    import pinocchio as pin

    return pin.SE3(_rz_rotation(deg), np.zeros(3))


def build_model(dh: DhTable, dynamics, base_T_mm=None):
    """A Pinocchio model (``pin.Model``) of the arm: 6 revolute joints, link masses/COMs/inertias, gravity -z."""
    import pinocchio as pin

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


def pack_model(dh: DhTable, dynamics, base_T_mm=None) -> np.ndarray:
    """The model :func:`build_model` builds, as the compiled kernel's float64 buffer (droid/_kernel.c
    ``rb_*``): per joint its placement in its parent's frame (rotation 3x3 row-major, translation 3
    [m]), its link's mass [kg], centre of mass (3 [m], joint frame) and inertia about the centre
    of mass (3x3 [kg m^2], joint frame); then gravity (3 [m/s^2]).  25 * 6 + 3 values."""
    base = np.eye(4) if base_T_mm is None else np.asarray(base_T_mm, float)
    R, p = base[:3, :3] @ _rz_rotation(dh.theta_offset_deg[0]), base[:3, 3] / 1000.0
    out = []
    for i in range(6):
        L = _link_rt(dh, i)
        com = L.rotation @ (np.asarray(dynamics.link_com_mm[i], float) / 1000.0) + L.translation
        inertia = L.rotation @ np.asarray(dynamics.link_inertia_kgm2[i], float) @ L.rotation.T
        out += [R.ravel(), p, [float(dynamics.link_mass_kg[i])], com, inertia.ravel()]
        if i < 5:
            R, p = L.rotation @ _rz_rotation(dh.theta_offset_deg[i + 1]), L.translation
    out.append([0.0, 0.0, -float(dynamics.gravity_mps2)])
    return np.ascontiguousarray(np.concatenate([np.asarray(v, float) for v in out]))


def world_backend() -> str:
    """The backend droid-sim's world uses: ``"kernel"`` when the compiled kernel is in use in this
    process (``DROID_KERNEL`` auto or c and :mod:`droid._kernel` built; :mod:`droid.kernel`) and
    has the rigid-body functions, else ``"pinocchio"`` (``DROID_KERNEL=python``, or an extension
    not built or built before them)."""
    from droid import kernel

    k = kernel.compiled()
    return "kernel" if k is not None and hasattr(k, "rb_rnea") else "pinocchio"


class RigidBody:
    """``M(q)``, ``M(q)^-1``, ``C(q, qd) qd + g(q)`` and the forward dynamics of an arm [SI: rad,
    rad/s, N m, kg m^2], with ``backend`` ``"pinocchio"`` (the default: Pinocchio's calls, the
    lockstep trials' bits) or ``"kernel"`` (droid._kernel's compiled RNEA/CRBA: no Pinocchio
    import; the module docstring).  Joint 6's frame and link 6: :meth:`wcp_mm`,
    :meth:`joint6_jacobian_world`, :attr:`link6`.  ``model``/``data`` are Pinocchio's (None with
    the kernel)."""

    def __new__(cls, dh: DhTable, dynamics, base_T_mm=None, backend: str = "pinocchio"):
        if backend not in BACKENDS:
            raise ValueError(f"rigid-body backend {backend!r}: known are {', '.join(BACKENDS)}")
        if cls is RigidBody and backend == "kernel":
            cls = KernelRigidBody
        return super().__new__(cls)

    def __init__(self, dh: DhTable, dynamics, base_T_mm=None, backend: str = "pinocchio") -> None:
        import pinocchio

        self.dh = dh
        self.backend = "pinocchio"
        self._pin = pinocchio
        self.model = build_model(dh, dynamics, base_T_mm)
        self.data = self.model.createData()
        self.link6 = _link_transform(dh, 5)  # link 6's D-H transform: joint 6's frame -> the wrist centre [m]
        self._upper = np.triu(np.ones((6, 6), bool))  # Pinocchio fills the upper triangle of M and Minv
        # nle(q, qd) without a Python frame: Pinocchio's own call on the same model and data (the
        # same bits); the plant's compiled exact step calls it every 2 ms (issue 44)
        self.nle_fn = functools.partial(pinocchio.nonLinearEffects, self.model, self.data)

    def minv(self, q_rad: np.ndarray) -> np.ndarray:
        """``M(q)^-1`` [1/(kg m^2)], full."""
        pin = self._pin
        pin.computeMinverse(self.model, self.data, q_rad)
        mi = self.data.Minv
        return np.where(self._upper, mi, mi.T)  # Pinocchio fills the upper triangle

    def mass(self, q_rad: np.ndarray) -> np.ndarray:
        """``M(q)`` [kg m^2], full."""
        pin = self._pin
        pin.crba(self.model, self.data, q_rad)
        m = self.data.M
        return np.where(self._upper, m, m.T)

    def bias(self, q_rad: np.ndarray, qd_rad_s: np.ndarray) -> np.ndarray:
        """``C(q, qd) qd + g(q)`` [N m], a new array."""
        return self.nle(q_rad, qd_rad_s).copy()

    def nle(self, q_rad: np.ndarray, qd_rad_s: np.ndarray) -> np.ndarray:
        """``C(q, qd) qd + g(q)`` [N m]; with Pinocchio its buffer (valid until the next call)."""
        pin = self._pin
        return pin.nonLinearEffects(self.model, self.data, q_rad, qd_rad_s)

    def gravity(self, q_rad: np.ndarray) -> np.ndarray:
        """``g(q)`` [N m], a new array."""
        pin = self._pin
        return pin.computeGeneralizedGravity(self.model, self.data, q_rad).copy()

    def aba(self, q_rad: np.ndarray, qd_rad_s: np.ndarray, tau_nm: np.ndarray) -> np.ndarray:
        """The forward dynamics ``qdd = M^-1 (tau - C qd - g)`` [rad/s^2]; with Pinocchio (``aba``)
        its buffer (valid until the next call)."""
        pin = self._pin
        return pin.aba(self.model, self.data, q_rad, qd_rad_s, tau_nm)

    def wcp_mm(self, q_deg) -> np.ndarray:
        """The wrist-centre pose (4x4, mm) of the model: joint 6's frame times link 6's transform."""
        pin = self._pin
        pin.forwardKinematics(self.model, self.data, np.radians(np.asarray(q_deg, float)))
        M = self.data.oMi[6] * self.link6
        T = np.eye(4)
        T[:3, :3] = M.rotation
        T[:3, 3] = M.translation * 1000.0
        return T

    def joint6_jacobian_world(self, q_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(J6, R6, o6)``: joint 6's 6x6 Jacobian in Pinocchio's LOCAL_WORLD_ALIGNED convention
        (rows: the velocity of joint 6's origin [m/s per rad/s], then the angular velocity; base
        axes), and joint 6's frame in the base frame: rotation (3x3) and origin [m]."""
        pin = self._pin
        model, data = self.model, self.data
        pin.computeJointJacobians(model, data, q_rad)
        J6 = pin.getJointJacobian(model, data, 6, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        M = data.oMi[6]
        return J6, M.rotation, M.translation


class KernelRigidBody(RigidBody):
    """:class:`RigidBody` on the compiled kernel (``RigidBody(..., backend="kernel")`` makes one):
    droid._kernel's RNEA and CRBA on the model packed once (:func:`pack_model`), never importing
    Pinocchio; ``model`` and ``data`` are None.  Every method returns a new array."""

    def __init__(self, dh: DhTable, dynamics, base_T_mm=None, backend: str = "kernel") -> None:
        from droid import kernel

        self._k = kernel.load_compiled()
        if not hasattr(self._k, "rb_rnea"):
            raise kernel.KernelUnavailable("droid._kernel was built without the rigid-body functions (rebuild it)")
        self.dh = dh
        self.backend = "kernel"
        self._buf = pack_model(dh, dynamics, base_T_mm)
        self.model = self.data = None
        self.nle_fn = self.nle
        self.link6 = _link_rt(dh, 5)  # link 6's D-H transform: joint 6's frame -> the wrist centre [m]
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.link6
        self._link6_T = T

    def minv(self, q_rad):
        out = np.empty((6, 6))
        self._k.rb_minv(self._buf, _f64(q_rad), out)
        return out

    def mass(self, q_rad):
        out = np.empty((6, 6))
        self._k.rb_crba(self._buf, _f64(q_rad), out)
        return out

    def nle(self, q_rad, qd_rad_s):
        out = np.empty(6)
        self._k.rb_rnea(self._buf, _f64(q_rad), _f64(qd_rad_s), None, True, out)
        return out

    bias = nle  # already a new array

    def gravity(self, q_rad):
        out = np.empty(6)
        self._k.rb_rnea(self._buf, _f64(q_rad), None, None, True, out)
        return out

    def aba(self, q_rad, qd_rad_s, tau_nm):
        out = np.empty(6)
        self._k.rb_aba(self._buf, _f64(q_rad), _f64(qd_rad_s), _f64(tau_nm), out)
        return out

    def wcp_mm(self, q_deg):
        oM = np.empty((4, 4))
        self._k.rb_jacobian(self._buf, np.radians(np.asarray(q_deg, float)), None, oM)
        T = oM @ self._link6_T
        T[:3, 3] *= 1000.0
        return T

    def joint6_jacobian_world(self, q_rad):
        J, oM = np.empty((6, 6)), np.empty((4, 4))
        self._k.rb_jacobian(self._buf, _f64(q_rad), J, oM)
        return J, oM[:3, :3], oM[:3, 3]


def _f64(x) -> np.ndarray:
    """``x`` as a C-contiguous float64 array (no copy when it is one already)."""
    return x if type(x) is np.ndarray and x.dtype == np.float64 and x.flags.c_contiguous else np.ascontiguousarray(x, float)
