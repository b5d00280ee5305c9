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

The surfaces (:func:`surface_contact`; the same lap joint as the sensors see, thesis §6.1.1):
in the seam's local frame at the nearest seam point (foot p, rolled normal n, lateral l;
``side = upper_sign (x - p).l``, ``z = (x - p).n``, ``h`` the step there, 0 in a gap):

* the lower side (``-width <= side < 0``): the surface z = 0, outward normal n, depth -z;
* the upper side (``0 <= side <= width``): the top z = h (depth ``h - z``, normal n) and
  the step's wall, the edge face at side = 0 for 0 < z < h (depth ``side``, outward normal
  ``-upper_sign l``, toward the lower side); the point is pushed out through the closer
  face (the smaller depth; a tie goes to the top).  A point that enters the upper plate's
  footprint from the side, below its top, is pushed sideways out of the wall by its small
  lateral penetration, not up by ``k (h - z)``;
* beside the surfaces (``|side| > width``) or before the lead-in / after the lead-out:
  nothing (depth -inf).

A plane workpiece is answered by its exact plane model (lines and arcs, normal +z_W:
bit for bit the horizontal surfaces' force as before the wall was added); a 3-D one
(rolled, climbing, a step profile, gaps) by its :class:`droid.sim.seam3d.Seam3D`
(:class:`SeamSurfaces`: the nearest point of the sampled foot, the frame of
``Seam3D.point_frame``).  Tacks are not modelled (the upper surface is flat over a tack;
the sensors see the bump, the contact does not); the normal of a varying step or roll is
the seam point's n (the ruled surface's slope along s is left out).

The parameters come from the workpiece file's ``[contact]`` table (droid.sim.workpiece;
ranges in droid.numbers).  :func:`contact_force` is the pure law; :class:`ToolContact`
puts it on an arm's plant: from the true joint angles and speeds it finds the tool point's
pose and velocity, asks the workpiece for the surface under it, and returns the joint
torques ``tau = J^T F`` (J the tool point's Jacobian) the plant adds in its step.
"""
from __future__ import annotations

import math
import weakref
from bisect import bisect_right
from dataclasses import dataclass, fields
from itertools import pairwise

import numpy as np

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


#: keys of a workpiece's ``[contact]`` table: the fields of ContactParams
CONTACT_KEYS = tuple(f.name for f in fields(ContactParams))

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


def lap_depth(side_mm: float, z_mm: float, h_mm: float) -> tuple[float, bool]:
    """(depth [mm], on the wall) of a point within the surfaces' width, in the seam's local
    frame: ``side_mm`` lateral (+ toward the upper plate), ``z_mm`` above the lower surface,
    the step ``h_mm`` high there (module docstring; thesis §7.3).  The lower side's depth is
    ``0 - z``; on the upper side the closer of the top (``h - z``) and the wall (``side``, only
    for 0 < z < h), a tie to the top.  Positive: inside."""
    if side_mm < 0.0:
        return 0.0 - z_mm, False
    depth = h_mm - z_mm
    if 0.0 < z_mm < h_mm and side_mm < depth:
        return side_mm, True
    return depth, False


# tests/sim/test_contact.py keeps a deliberate copy of this law as it was before the wall (its reference).
def _face_force(depth_mm: float, n, v_mm_s, params: ContactParams, slip_limit) -> np.ndarray:
    """The law on one face (unit outward normal ``n``, global): the normal rate and the
    sliding velocity from the point's velocity, friction capped by ``slip_limit``."""
    v = np.asarray(v_mm_s, float)
    vn = float(v @ n)
    vt = v - vn * n
    limit = math.inf
    if slip_limit is not None:
        speed = math.sqrt(float(vt @ vt))
        if speed > 0.0:
            limit = slip_limit(vt / speed)
    return contact_force(depth_mm, -vn, n, vt, params, limit)


def surface_contact(workpiece, T_global_W: np.ndarray, p_mm, v_mm_s, params: ContactParams,
                    slip_limit=None) -> tuple[np.ndarray, float]:
    """(force [N] in the global frame, depth [mm]) on a point at ``p_mm`` moving at ``v_mm_s``
    (global frame) against a workpiece at ``T_global_W``: the face the point is pushed out
    through (module docstring: the lower surface, the upper one's top or the step's wall; none
    beside the workpiece: depth -inf).  ``slip_limit(t_unit_global)`` [N], if given, caps the
    friction along the sliding direction.

    A plane workpiece: its plane model (the point's x-y position in W, the lower plate
    z_W = 0, the upper z_W = ``step_mm``, normal +z_W; the wall's normal horizontal,
    ``-upper_sign`` x the seam's left normal).  A 3-D one: :class:`SeamSurfaces`."""
    if not workpiece.planar:
        f, depth, _ = seam_contact(surfaces_for(workpiece), T_global_W, p_mm, v_mm_s, params, slip_limit)
        return f, depth
    R = T_global_W[:3, :3]
    p_W = R.T @ (np.asarray(p_mm, float) - T_global_W[:3, 3])
    s, lat = workpiece.nearest_many(p_W[None, 0:2])  # as surface_height(): the same arithmetic
    h = float(workpiece.heights_from(s, lat)[0])
    if math.isnan(h):  # beside the workpiece: nothing under the point
        return ZERO3.copy(), -math.inf
    depth, wall = lap_depth(workpiece.upper_sign * float(lat[0]), float(p_W[2]), h)
    if not depth > 0.0:
        return ZERO3.copy(), depth
    if wall:  # out of the step's wall, toward the lower side: -upper_sign x the left normal
        _, heading = workpiece.point_at(float(s[0]))
        us = workpiece.upper_sign
        n = R @ np.array([us * math.sin(heading), -us * math.cos(heading), 0.0])
    else:
        n = R[:, 2]
    return _face_force(depth, n, v_mm_s, params, slip_limit), depth


#: Segments of the foot per bounding sphere in :meth:`SeamSurfaces.nearest`'s search.
CHUNK_SEGMENTS = 16
#: Slack [mm] on a 3-D workpiece's reach (:class:`ToolContact`): covers the offset of a point
#: along the tangent of its nearest seam point (the frame's interpolated tangent against the
#: foot's chords: under 0.1 mm over a surface's width on the shipped workpieces).
REACH_MARGIN_MM = 1.0


class SeamSurfaces:
    """The lap joint's surfaces around a 3-D seam (:class:`droid.sim.seam3d.Seam3D`), for
    contact (module docstring; thesis §7.3).

    :meth:`nearest` finds the nearest point of the sampled foot (the polyline through
    ``seam.p``, exactly: every segment's projection, the segments searched in bounding
    spheres of :data:`CHUNK_SEGMENTS`); :meth:`frame` is ``Seam3D.point_frame`` in plain
    floats (the same arithmetic, a few times faster; a test holds them together);
    :meth:`depth` is :func:`lap_depth` in that frame."""

    def __init__(self, seam) -> None:
        self.seam = seam
        P = np.asarray(seam.p, float)
        self._s = [float(v) for v in seam.s]
        self._p, self._t, self._n0 = P.tolist(), np.asarray(seam.t).tolist(), np.asarray(seam.n0).tolist()
        self._P0 = P[:-1].copy()
        self._D = P[1:] - P[:-1]
        L2 = np.einsum("ij,ij->i", self._D, self._D)
        self._inv = np.where(L2 > 0.0, 1.0 / np.where(L2 > 0.0, L2, 1.0), 0.0)
        n = len(self._D)
        # the long straight extensions alone, the samples between in chunks
        edges = sorted({0, n - 1, n} | set(range(1, n - 1, CHUNK_SEGMENTS)))
        centres, rho = [], []
        for a, b in pairwise(edges):
            ends = P[a:b + 1]
            c = 0.5 * (ends.min(axis=0) + ends.max(axis=0))
            centres.append(c)
            rho.append(float(np.sqrt(np.max(np.sum((ends - c) ** 2, axis=1)))))
        self._centres, self._rho = np.array(centres), np.array(rho)
        self._sizes = np.diff(edges)
        self._roll = (np.array([a for a, _ in seam.roll_profile]), np.array([r for _, r in seam.roll_profile])) \
            if seam.roll_profile else None
        self._step = (np.array([a for a, _ in seam.step_profile]), np.array([h for _, h in seam.step_profile])) \
            if seam.step_profile else None
        self.upper_sign = float(seam.upper_sign)
        self.width_mm = float(seam.width_mm)
        self.along_mm = seam.along_mm
        #: the highest step [mm] along the seam (tacks left out, as in the force)
        self.max_step_mm = max([float(seam.step_mm), *(h for _, h in seam.step_profile), float(np.max(seam.h))])

    def nearest(self, x_W) -> tuple[float, float]:
        """(s [mm], distance [mm]) of the foot's point nearest to ``x_W`` (W, mm)."""
        x = np.asarray(x_W, float)
        dc = self._centres - x
        r = np.sqrt(np.einsum("ij,ij->i", dc, dc))
        near = r - self._rho <= float(np.min(r + self._rho))  # may hold the nearest point
        idx = np.flatnonzero(np.repeat(near, self._sizes))
        D = self._D[idx]
        d = x - self._P0[idx]
        a = np.minimum(np.maximum(np.einsum("ij,ij->i", d, D) * self._inv[idx], 0.0), 1.0)
        off = d - a[:, None] * D
        d2 = np.einsum("ij,ij->i", off, off)
        j = int(np.argmin(d2))
        k = int(idx[j])
        return self._s[k] + float(a[j]) * (self._s[k + 1] - self._s[k]), math.sqrt(float(d2[j]))

    def frame(self, s_mm: float):
        """(p, t, n, l) at arc length s [mm], as lists: ``Seam3D.point_frame``'s arithmetic."""
        S = self._s
        i = min(max(bisect_right(S, s_mm) - 1, 0), len(S) - 2)
        ds = S[i + 1] - S[i]
        f = 0.0 if ds <= 0 else (s_mm - S[i]) / ds
        g = 1 - f
        p = [g * a + f * b for a, b in zip(self._p[i], self._p[i + 1])]
        t = [g * a + f * b for a, b in zip(self._t[i], self._t[i + 1])]
        k = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
        t = [c / k for c in t]
        n0 = [g * a + f * b for a, b in zip(self._n0[i], self._n0[i + 1])]
        dot = n0[0] * t[0] + n0[1] * t[1] + n0[2] * t[2]
        n0 = [a - dot * b for a, b in zip(n0, t)]
        k = math.sqrt(n0[0] * n0[0] + n0[1] * n0[1] + n0[2] * n0[2])
        n0 = [c / k for c in n0]
        l0 = [n0[1] * t[2] - n0[2] * t[1], n0[2] * t[0] - n0[0] * t[2], n0[0] * t[1] - n0[1] * t[0]]
        if self._roll is None:
            return p, t, n0, l0
        r = float(np.interp(s_mm, *self._roll))
        c, sn = math.cos(r), math.sin(r)
        return p, t, [c * a - sn * b for a, b in zip(n0, l0)], [c * b + sn * a for a, b in zip(n0, l0)]

    def step_mm(self, s_mm: float) -> float:
        """The step [mm] at s: ``Seam3D.step_at``'s (the profile's or ``step_mm``, 0 in a gap)."""
        for a, b in self.seam.gaps:
            if a <= s_mm <= b:
                return 0.0
        return float(np.interp(s_mm, *self._step)) if self._step is not None else self.seam.step_mm

    def depth(self, x_W, reach_mm: float = math.inf) -> tuple[float, list | None, float]:
        """(depth [mm], the face's outward normal in W or None, distance to the foot [mm]) of a
        point ``x_W`` (W, mm): :func:`lap_depth` in the frame of its nearest seam point.  Depth
        -inf (normal None): beside the surfaces, before the lead-in or after the lead-out, or
        farther than ``reach_mm`` from the foot (:class:`ToolContact`: no point within reach of
        the plates is farther)."""
        s, dist = self.nearest(x_W)
        if dist > reach_mm or not self.along_mm[0] <= s <= self.along_mm[1]:
            return -math.inf, None, dist
        p, _, n, l = self.frame(s)
        r = [float(x_W[0]) - p[0], float(x_W[1]) - p[1], float(x_W[2]) - p[2]]
        side = self.upper_sign * (r[0] * l[0] + r[1] * l[1] + r[2] * l[2])
        if not -self.width_mm <= side <= self.width_mm:
            return -math.inf, None, dist
        z = r[0] * n[0] + r[1] * n[1] + r[2] * n[2]
        depth, wall = lap_depth(side, z, self.step_mm(s) if side >= 0.0 else 0.0)
        if wall:
            us = self.upper_sign
            return depth, [-us * l[0], -us * l[1], -us * l[2]], dist
        return depth, n, dist


_SURFACES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def surfaces_for(workpiece) -> SeamSurfaces:
    """The :class:`SeamSurfaces` of a workpiece's seam (built once per seam)."""
    seam = workpiece.seam
    out = _SURFACES.get(seam)
    if out is None:
        out = _SURFACES[seam] = SeamSurfaces(seam)
    return out


def seam_contact(surfaces: SeamSurfaces, T_global_W: np.ndarray, p_mm, v_mm_s, params: ContactParams,
                 slip_limit=None, reach_mm: float = math.inf) -> tuple[np.ndarray, float, float]:
    """:func:`surface_contact` on a seam's surfaces (any workpiece, by :func:`surfaces_for`):
    (force [N] global, depth [mm], the point's distance [mm] to the foot)."""
    R = T_global_W[:3, :3]
    x_W = R.T @ (np.asarray(p_mm, float) - T_global_W[:3, 3])
    depth, normal, dist = surfaces.depth(x_W, reach_mm)
    if not depth > 0.0:
        return ZERO3.copy(), depth, dist
    return _face_force(depth, R @ np.array(normal), v_mm_s, params, slip_limit), depth, dist


def _skew(r) -> np.ndarray:
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


class ToolContact:
    """A workpiece's surface pushing on an arm's tool point, as joint torques for its plant.

    ``workpiece`` (plane or 3-D, with ``contact`` params or ``params``) sits at ``T_global_W``;
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

    Skipping while far (``max_closing_speed_mm_s``): after a step that found the tool point
    c mm from anywhere it could touch, the next c / max_closing_speed_mm_s seconds are not
    asked.  On a plane workpiece c is the height above the top plate (no search), or the
    larger of the depth past the plates (``max_depth_mm``) and the distance beside the
    surfaces' width (:meth:`_clearance_mm`).  On a 3-D workpiece it is the point's distance
    to the foot (the sampled seam, exactly) less the reach ``sqrt(width^2 + max(step,
    max_depth)^2) + REACH_MARGIN_MM``: a point that touches lies within ``width`` of the
    foot laterally and within ``max(step, max_depth)`` along the normal, so no point nearer
    than the reach to the foot can touch, and a point farther is answered as beside the
    surfaces (depth -inf) -- the bound holds by construction, kinks and all.  Without
    ``max_depth_mm`` a 3-D workpiece's surfaces reach any depth: every step is asked.
    """

    SLIP_CAP = 1.0

    def __init__(self, workpiece, T_global_W, T_global_base, T_wcp_tool, params: ContactParams | None = None,
                 max_closing_speed_mm_s: float | None = None, max_depth_mm: float | None = None) -> None:
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
        # a 3-D workpiece: its seam's surfaces, and how far from the foot a touching point can be
        self._surfaces = None if workpiece.planar else surfaces_for(workpiece)
        self._reach_mm = math.inf
        if self._surfaces is not None and max_depth_mm is not None:
            sf = self._surfaces
            self._reach_mm = math.hypot(sf.width_mm, max(sf.max_step_mm, float(max_depth_mm))) + REACH_MARGIN_MM
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
        """A plane workpiece's lower bound on the distance [mm] from a point in W, not above the
        top surface (that case is answered first in :meth:`joint_torque`), to where it could
        touch: below the plates (with ``max_depth_mm``) or beside the surfaces' footprint
        (farther than ``width_mm`` from the seam and its leads; the wall lies within it).  <= 0:
        it may touch.  (A 3-D workpiece's: the class docstring.)"""
        gap = -math.inf if self.max_depth_mm is None else -self.max_depth_mm - float(p_W[2])
        _, lat = self.workpiece.nearest_many(p_W[None, 0:2])
        return max(gap, abs(float(lat[0])) - float(self.workpiece.width_mm))

    def contact_wrench_N_Nm(self) -> tuple[np.ndarray, np.ndarray]:
        """The wrench on the tool, global frame: force [N], torque about the tool point [N m]
        (a point contact at the tool point: zero)."""
        return self.force_N.copy(), np.zeros(3)

    def tool_state(self, body, q_rad, qd_rad_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tool point [mm], its velocity [mm/s], both global; J_t (3x6) [m/rad], base frame)."""
        if self._link6 is None:
            L = body.link6
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = L.rotation, L.translation
            tool = self.T_wcp_tool.copy()
            tool[:3, 3] *= 1e-3
            self._link6 = T @ tool  # joint 6's frame -> the tool point [m]
        J6, R6, o6 = body.joint6_jacobian_world(q_rad)  # LOCAL_WORLD_ALIGNED; joint 6's frame [m]
        p_base = R6 @ self._link6[:3, 3] + o6  # [m]
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
        if self.max_closing_speed_mm_s is not None and self._surfaces is None:
            # above every surface of a plane workpiece (the cheap test first: no search for the surface under it)
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

        if self._surfaces is None:
            f, depth = surface_contact(self.workpiece, T_W, p, v, self.params, slip_limit)
        else:
            f, depth, foot_mm = seam_contact(self._surfaces, T_W, p, v, self.params, slip_limit, self._reach_mm)
        if self.max_depth_mm is not None and depth > self.max_depth_mm:
            f = np.zeros(3)  # behind the plate
        self.depth_mm = depth
        self.force_N = f
        if not f.any():
            if self.max_closing_speed_mm_s is not None:
                if self._surfaces is None:
                    clearance = self._clearance_mm(T_W[:3, :3].T @ (p - T_W[:3, 3]))
                else:
                    clearance = foot_mm - self._reach_mm
                if clearance > 0.0:
                    self._skip_s = clearance / self.max_closing_speed_mm_s - dt_s
            return None
        return J_t.T @ (Rg.T @ f)
