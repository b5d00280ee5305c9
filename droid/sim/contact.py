"""Contact between the tool point and a workpiece's surface (issue 27 item 4; thesis §7.3).

The thesis ends with force control as the next task a DROID cell should take on (§7.3);
the world needs contact for it.  The model is a penalty contact at the tool point
(docs/contact.md):

* **normal**: where the tool point is ``depth`` [mm] below the surface (along the surface
  normal **n**), the surface pushes back along **n** with
  ``F_n = k depth + c depth_rate`` [N] (``k`` = ``stiffness_n_per_mm``, ``c`` =
  ``damping_n_s_per_mm``, ``depth_rate`` [mm/s] the rate of penetration), never pulling
  (``F_n >= 0``); zero where the tool is above the surface or beside the workpiece;
* **friction**: Coulomb along the surface, ``|F_t| <= mu F_n`` (``mu`` =
  ``friction_coefficient``) against the sliding velocity; below ``slip_speed_mm_s`` the
  force grows linearly with the sliding speed (a regularised Coulomb law: no sticking
  state to switch), and ``slip_limit_n`` caps it at the force that would stop the sliding
  in one integration step (an explicit step of a stiff friction law would otherwise
  overshoot and reverse: see :class:`ToolContact`).

The parameters come from the workpiece file's ``[contact]`` table (droid.sim.workpiece;
ranges in droid.numbers).  :func:`contact_force` is the pure law; :class:`ToolContact`
puts it on an arm's plant: from the true joint angles and speeds it finds the tool point's
pose and velocity, asks the workpiece for the surface under it, and returns the joint
torques ``tau = J^T F`` (J the tool point's Jacobian) the plant adds in its step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: keys of a workpiece's ``[contact]`` table
CONTACT_KEYS = ("stiffness_n_per_mm", "damping_n_s_per_mm", "friction_coefficient", "slip_speed_mm_s")


@dataclass(frozen=True)
class ContactParams:
    """A penalty contact: normal stiffness [N/mm] and damping [N s/mm], Coulomb friction."""

    stiffness_n_per_mm: float = 20.0
    damping_n_s_per_mm: float = 0.05
    friction_coefficient: float = 0.3
    slip_speed_mm_s: float = 2.0  # below it the friction force grows linearly with the sliding speed

    @classmethod
    def from_table(cls, table: dict, bad) -> "ContactParams":
        """From a ``[contact]`` table (numbers already range-checked by droid.numbers); ``bad(msg)``
        makes the loader's error.  Every key is optional (the defaults above)."""
        if not isinstance(table, dict):
            raise bad("[contact] must be a table")
        unknown = sorted(set(table) - set(CONTACT_KEYS))
        if unknown:
            raise bad(f"[contact]: unknown key {unknown[0]!r} (expected one of {', '.join(CONTACT_KEYS)})")
        return cls(**{k: float(v) for k, v in table.items()})


ZERO3 = np.zeros(3)


def contact_force(depth_mm: float, depth_rate_mm_s: float, normal, v_tangent_mm_s, params: ContactParams,
                  slip_limit_n: float = math.inf) -> np.ndarray:
    """The force [N] (3,) a surface applies to a point ``depth_mm`` below it (module docstring).

    ``normal``: the surface's unit outward normal; ``v_tangent_mm_s``: the point's velocity
    along the surface [mm/s] (perpendicular to ``normal``); ``depth_rate_mm_s``: d(depth)/dt.
    Zero when ``depth_mm <= 0`` (apart) or when the damping would pull (``F_n < 0``)."""
    if not depth_mm > 0.0:
        return ZERO3.copy()
    fn = params.stiffness_n_per_mm * depth_mm + params.damping_n_s_per_mm * depth_rate_mm_s
    if not fn > 0.0:
        return ZERO3.copy()
    n = np.asarray(normal, float)
    vt = np.asarray(v_tangent_mm_s, float)
    speed = math.sqrt(float(vt @ vt))
    f = fn * n
    if speed > 0.0 and params.friction_coefficient > 0.0:
        ft = params.friction_coefficient * fn * min(1.0, speed / params.slip_speed_mm_s)
        ft = min(ft, slip_limit_n)
        f = f - (ft / speed) * vt
    return f


def surface_contact(workpiece, T_global_W: np.ndarray, p_mm, v_mm_s, params: ContactParams,
                    slip_limit=None) -> tuple[np.ndarray, float]:
    """(force [N] in the global frame, depth [mm]) on a point at ``p_mm`` moving at ``v_mm_s``
    (global frame) against a plane workpiece at ``T_global_W``: the surface under the point's
    x-y position in W (the lower plate z_W = 0, the upper z_W = step_mm; none beside the
    workpiece: depth -inf), its normal +z_W.  ``slip_limit(t_unit_global)`` [N], if given, caps the
    friction along the sliding direction."""
    R = T_global_W[:3, :3]
    p_W = R.T @ (np.asarray(p_mm, float) - T_global_W[:3, 3])
    h = workpiece.surface_height(p_W[0:2])
    if h is None:  # beside the workpiece: nothing under the point
        return ZERO3.copy(), -math.inf
    depth = h - float(p_W[2])
    if not depth > 0.0:
        return ZERO3.copy(), depth
    n = R[:, 2]
    v = np.asarray(v_mm_s, float)
    vn = float(v @ n)
    vt = v - vn * n
    limit = math.inf
    if slip_limit is not None:
        speed = math.sqrt(float(vt @ vt))
        if speed > 0.0:
            limit = slip_limit(vt / speed)
    return contact_force(depth, -vn, n, vt, params, limit), depth


def _skew(r) -> np.ndarray:
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


class ToolContact:
    """A workpiece's surface pushing on an arm's tool point, as joint torques for its plant.

    ``workpiece`` (a plane one, with ``contact`` params or ``params``) sits at ``T_global_W``;
    the arm's base at ``T_global_base``; the tool point at ``T_wcp_tool`` on the wrist centre
    (the seam layout's 250 mm torch).  :meth:`joint_torque` is called by the plant
    (:class:`droid.sim.reis.plant.ReisPlant`) at the start of each step with its true link
    angles and speeds: it returns ``tau = J^T F`` [N m] (None while apart: the plant's step is
    then exactly what it was without contact) and keeps the wrench for
    :meth:`contact_wrench_N_Nm` (the F/T twin's hook, docs/ft.md).

    The force is held over the plant's step (zero-order hold, as its other nonlinear torques).
    Friction is capped at ``SLIP_CAP`` x the force that would stop the tool's sliding within
    the step given the links' inertia at the tool point, ``|v_t| / (dt t^T J M^-1 J^T t)``:
    the regularised law's slope (mu F_n / slip speed, ~3 N s/mm at 20 N) on the wrist's
    small inertia (~0.4 kg at the tool point through joint 4) would otherwise make the
    explicit step diverge (slope x dt / mass >> 2).  A friction force b v with b dt / m = c
    scales the sliding speed by (1 - c) each step: 1 (deadbeat) is stable with margin (the
    limit is 2), and the link-only inertia is the smallest the tool can show (the drives add
    the motors' behind it), so the cap errs on the stable side.  At 10 mm/s it lets the full
    mu F_n act (the contact trial: 5.98 N at 19.92 N, mu = 0.3).
    """

    SLIP_CAP = 1.0

    def __init__(self, workpiece, T_global_W, T_global_base, T_wcp_tool, params: ContactParams | None = None,
                 max_closing_speed_mm_s: float | None = None, max_depth_mm: float | None = None) -> None:
        if not workpiece.planar:
            raise ValueError(f"workpiece {workpiece.name}: contact is modelled on plane workpieces only")
        p = params if params is not None else getattr(workpiece, "contact", None)
        if p is None:
            raise ValueError(f"workpiece {workpiece.name}: no [contact] table (and no contact parameters given)")
        self.params = p
        self.workpiece = workpiece
        # a fixed 4x4, or a callable giving it now (a workpiece on a holder's wrist: make_contact)
        self._T_W_now = T_global_W if callable(T_global_W) else None
        self._T_W_fixed = None if callable(T_global_W) else np.asarray(T_global_W, float)
        # Skipping while far (the world device only): with the tool point c mm from the region
        # where it could touch (_clearance_mm), nothing can touch for c / max_closing_speed_mm_s
        # seconds, so the steps in between are not asked (each would answer None: the plant's
        # step is the same).  None: every step is asked (lockstep trials read tool_mm each cycle).
        self.max_closing_speed_mm_s = max_closing_speed_mm_s
        # The plates' thickness [mm] (the world device only): a point deeper than this under a
        # surface is behind the plate, not in it -- no push.  Without it the penalty treats the
        # workpiece as a solid of any depth, and a tool swung in under it from the side (a joint
        # move past a vertical workpiece) would meet depth x k newtons at once.  None: any depth.
        self.max_depth_mm = max_depth_mm
        self._top_mm = max(0.0, float(getattr(workpiece, "step_mm", 0.0)))
        self._skip_s = 0.0
        self.evaluations = 0  # steps asked in full (the skip's effect, for tests and benchmarks)
        self.T_global_base = np.asarray(T_global_base, float)
        self.T_wcp_tool = np.asarray(T_wcp_tool, float)
        self.force_N = np.zeros(3)  # the newest contact force on the tool, global frame [N]
        self.depth_mm = 0.0  # the newest penetration depth [mm] (negative: above the surface)
        self.tool_mm = np.zeros(3)  # the newest tool point, global frame [mm]
        self.tool_v_mm_s = np.zeros(3)
        self._link6 = None

    @property
    def T_global_W(self) -> np.ndarray:
        """The workpiece frame W in the global frame now (4x4, mm)."""
        return self._T_W_fixed if self._T_W_now is None else np.asarray(self._T_W_now(), float)

    def _clearance_mm(self, p_W: np.ndarray) -> float:
        """A lower bound on the distance [mm] from a point in W, not above the top surface (that
        case is answered first in :meth:`joint_torque`), to where it could touch: below the plates
        (with ``max_depth_mm``) or beside the surfaces' footprint (farther than ``width_mm`` from
        the seam and its leads).  <= 0: it may touch."""
        gap = -math.inf if self.max_depth_mm is None else -self.max_depth_mm - float(p_W[2])
        _, lat = self.workpiece.nearest_many(p_W[None, 0:2])
        return max(gap, abs(float(lat[0])) - float(self.workpiece.width_mm))

    def contact_wrench_N_Nm(self) -> tuple[np.ndarray, np.ndarray]:
        """The wrench on the tool, global frame: force [N], torque about the tool point [N m]
        (a point contact at the tool point: zero)."""
        return self.force_N.copy(), np.zeros(3)

    def tool_state(self, body, q_rad, qd_rad_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tool point [mm], its velocity [mm/s], both global; J_t (3x6) [m/rad], base frame)."""
        import pinocchio as pin

        model, data = body.model, body.data
        if self._link6 is None:
            L = body.link6
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = L.rotation, L.translation
            tool = self.T_wcp_tool.copy()
            tool[:3, 3] *= 1e-3
            self._link6 = T @ tool  # joint 6's frame -> the tool point [m]
        pin.computeJointJacobians(model, data, q_rad)
        J6 = pin.getJointJacobian(model, data, 6, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        M = data.oMi[6]
        o6 = M.translation
        p_base = M.rotation @ self._link6[:3, 3] + o6  # [m]
        J_t = J6[:3] - _skew(p_base - o6) @ J6[3:]
        v_base = J_t @ qd_rad_s
        Rg = self.T_global_base[:3, :3]
        p = Rg @ (p_base * 1e3) + self.T_global_base[:3, 3]
        return p, Rg @ (v_base * 1e3), J_t

    def joint_torque(self, body, q_rad, qd_rad_s, dt_s: float) -> np.ndarray | None:
        """``J^T F`` [N m] on the six joints, or None while the tool is off the surface."""
        if self._skip_s > 0.0:
            self._skip_s -= dt_s
            return None
        self.evaluations += 1
        p, v, J_t = self.tool_state(body, q_rad, qd_rad_s)
        self.tool_mm, self.tool_v_mm_s = p, v
        T_W = self.T_global_W
        if self.max_closing_speed_mm_s is not None:
            # above every surface (the cheap test first: no search for the surface under it)
            gap = float(T_W[:3, 2] @ (p - T_W[:3, 3])) - self._top_mm
            if gap > 0.0:
                self.depth_mm, self.force_N = -gap, np.zeros(3)  # depth: at least this far above
                self._skip_s = gap / self.max_closing_speed_mm_s - dt_s
                return None
        Rg = self.T_global_base[:3, :3]

        def slip_limit(t_global) -> float:
            t = Rg.T @ t_global
            jt = J_t.T @ t
            mobility = float(jt @ body.minv(q_rad) @ jt)  # 1/kg at the tool point along t
            speed = float(t_global @ v) * 1e-3  # [m/s]
            return self.SLIP_CAP * abs(speed) / (dt_s * mobility) if mobility > 0 else math.inf

        f, depth = surface_contact(self.workpiece, T_W, p, v, self.params, slip_limit)
        if self.max_depth_mm is not None and depth > self.max_depth_mm:
            f = np.zeros(3)  # behind the plate
        self.depth_mm = depth
        self.force_N = f
        if not f.any():
            if self.max_closing_speed_mm_s is not None:
                clearance = self._clearance_mm(T_W[:3, :3].T @ (p - T_W[:3, 3]))
                if clearance > 0.0:
                    self._skip_s = clearance / self.max_closing_speed_mm_s - dt_s
            return None
        return J_t.T @ (Rg.T @ f)
