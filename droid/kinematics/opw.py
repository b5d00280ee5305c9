"""Analytic kinematics of ortho-parallel 6R arms with a spherical wrist (OPW class).

The thesis solves the Reis Robotstar V15 geometrically (§4.1.1.2, the
cart_to_joint() listing of §4.1.7): joint 1 from atan2 of the wrist-centre
point (WCP), joints 2 and 3 from the law of cosines in the arm plane, joints
4-6 as Z-Y-Z Euler angles of ``R_03^T R`` (eq. 4.5-4.9).  This module is that
solution written for the parameter set of Brandstötter et al. (2014), as in
opw_kinematics (the ROS-Industrial library), so any arm of the class is a data file:

    a1, a2, b, c1, c2, c3, c4  [mm]      geometry (zero pose: arm straight up)
    signs[6] (+1/-1), offsets_deg[6]     q_opw = sign * q - offset

``q`` are the robot's own joint angles (for the bundled robots the thesis's
D-H joint variables, Table 4.1); ``q_opw`` the model's.  Everything here is a
pure function of the parameters: no limits, no state.

Solution numbering (the thesis's cart_to_joint(solution) numbering)::

    index = 4 * shoulder + 2 * elbow + wrist
    shoulder 0: WCP in front of the joint-1 axis;   1: reached over the back
    elbow    0: q3_opw + psi3 = +acos(D);           1: = -acos(D)
    wrist    0: q5_opw >= 0;                        1: q5_opw <= 0

For the Reis these are the thesis's ``d2 > 0`` / ``Ds > 0`` / ``Rr > 0``
branches (cos(theta3) >= 0 is elbow 0, theta5 >= 0 is wrist 0).

Singularity policy (documented in docs/kinematics.md):

* shoulder (WCP on the joint-1 axis, b = 0): q1 = the hint (previous q1), the
  back branch q1 + 180 deg;
* elbow (arm fully stretched or folded, |D| = 1 within ELBOW_EPS): D is
  clamped, both elbow branches coincide; |D| > 1 + ELBOW_EPS is unreachable;
* wrist (sin q5 < WRIST_EPS): q4 = the hint (previous q4), the whole rotation
  about the wrist axis goes into q6 (as the thesis's ``Beta == 0`` branch).
  q6 is always computed from the residual rotation, so the round trip is
  exact for any q4.

Angles returned are wrapped to (-180, 180] degrees; a solution that does not
exist is a row of NaN.  This module holds the scalar forms (math module, one
pose, a few microseconds); :mod:`droid.kinematics.opw_batch` the batched numpy
forms (N poses); they agree to rounding.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

NAN = float("nan")
PI = math.pi
DEG = 180.0 / math.pi
RAD = math.pi / 180.0

#: sqrt(x^2 + y^2) [mm] of the WCP below which it is on the joint-1 axis.
SHOULDER_EPS_MM = 1e-9
#: tolerance on the elbow cosine D beyond +-1 that is still "fully stretched".
ELBOW_EPS = 1e-10
#: |sin q5| below which the wrist is singular.
WRIST_EPS = 1e-9

_SIX = 6


# Alike in shape only to other numeric dataclasses (seam3d's ToolReading): geometry, not a reading.
@dataclass(frozen=True)
class OpwParams:
    """OPW geometry [mm] and the joint map ``q_opw = sign * q - offset`` [deg]."""

    a1: float
    a2: float
    b: float
    c1: float
    c2: float
    c3: float
    c4: float
    offsets_deg: tuple = (0.0,) * 6
    signs: tuple = (1,) * 6
    # derived constants (filled in __post_init__)
    _k: float = field(init=False, repr=False, compare=False)
    _psi3: float = field(init=False, repr=False, compare=False)
    _gain: tuple = field(init=False, repr=False, compare=False)
    _bias: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        vals = (self.a1, self.a2, self.b, self.c1, self.c2, self.c3, self.c4)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError("opw: geometry must be finite numbers [mm]")
        if self.c2 <= 0 or math.hypot(self.a2, self.c3) <= 0:
            raise ValueError("opw: c2 and hypot(a2, c3) must be > 0 mm")
        offs = tuple(float(o) for o in self.offsets_deg)
        signs = tuple(int(s) for s in self.signs)
        if len(offs) != _SIX or not all(math.isfinite(o) for o in offs):
            raise ValueError("opw: offsets_deg must be 6 finite numbers")
        if len(signs) != _SIX or any(s not in (1, -1) for s in signs):
            raise ValueError("opw: signs must be 6 entries of +1 or -1")
        object.__setattr__(self, "offsets_deg", offs)
        object.__setattr__(self, "signs", signs)
        object.__setattr__(self, "_k", math.hypot(self.a2, self.c3))
        object.__setattr__(self, "_psi3", math.atan2(self.a2, self.c3))
        # q_user_deg = gain * q_opw_rad + bias
        object.__setattr__(self, "_gain", tuple(s * DEG for s in signs))
        object.__setattr__(self, "_bias", tuple(s * o for s, o in zip(signs, offs)))

    @property
    def reach_mm(self) -> float:
        """Largest shoulder-to-WCP distance [mm] (arm stretched)."""
        return self.c2 + self._k


def wrap_scalar(angle_deg: float) -> float:
    """Wrap one angle [deg] into (-180, 180] exactly."""
    w = math.remainder(angle_deg, 360.0)
    return 180.0 if w == -180.0 else w


# --------------------------------------------------------------------------
# scalar forms (math module): one pose
# --------------------------------------------------------------------------


def fk(p: OpwParams, q_deg) -> list:
    """Forward kinematics of one joint vector [deg] -> 3x4 [R | t] as nested lists (mm)."""
    sg, of = p.signs, p.offsets_deg
    q1 = (sg[0] * q_deg[0] - of[0]) * RAD
    q2 = (sg[1] * q_deg[1] - of[1]) * RAD
    q3 = (sg[2] * q_deg[2] - of[2]) * RAD
    q4 = (sg[3] * q_deg[3] - of[3]) * RAD
    q5 = (sg[4] * q_deg[4] - of[4]) * RAD
    q6 = (sg[5] * q_deg[5] - of[5]) * RAD
    s1, c1 = math.sin(q1), math.cos(q1)
    s2, c2 = math.sin(q2), math.cos(q2)
    s23, c23 = math.sin(q2 + q3), math.cos(q2 + q3)
    s4, c4 = math.sin(q4), math.cos(q4)
    s5, c5 = math.sin(q5), math.cos(q5)
    s6, c6 = math.sin(q6), math.cos(q6)
    # WCP in the arm plane, then about joint 1
    cx1 = p.c2 * s2 + p.c3 * s23 + p.a2 * c23 + p.a1
    cz1 = p.c2 * c2 + p.c3 * c23 - p.a2 * s23
    cx = cx1 * c1 - p.b * s1
    cy = cx1 * s1 + p.b * c1
    cz = cz1 + p.c1
    # R_0c = Rz(q1) Ry(q2+q3);  R_ce = Rz(q4) Ry(q5) Rz(q6)
    e00 = c4 * c5 * c6 - s4 * s6
    e01 = -c4 * c5 * s6 - s4 * c6
    e02 = c4 * s5
    e10 = s4 * c5 * c6 + c4 * s6
    e11 = -s4 * c5 * s6 + c4 * c6
    e12 = s4 * s5
    e20 = -s5 * c6
    e21 = s5 * s6
    e22 = c5
    # rows of R_0c: [c1 c23, -s1, c1 s23], [s1 c23, c1, s1 s23], [-s23, 0, c23]
    u0 = c23 * e00 + s23 * e20
    u1 = c23 * e01 + s23 * e21
    u2 = c23 * e02 + s23 * e22
    r00 = c1 * u0 - s1 * e10
    r01 = c1 * u1 - s1 * e11
    r02 = c1 * u2 - s1 * e12
    r10 = s1 * u0 + c1 * e10
    r11 = s1 * u1 + c1 * e11
    r12 = s1 * u2 + c1 * e12
    r20 = -s23 * e00 + c23 * e20
    r21 = -s23 * e01 + c23 * e21
    r22 = -s23 * e02 + c23 * e22
    c4m = p.c4
    return [
        [r00, r01, r02, cx + c4m * r02],
        [r10, r11, r12, cy + c4m * r12],
        [r20, r21, r22, cz + c4m * r22],
    ]


def ik(p: OpwParams, t, hint1_deg: float = 0.0, hint4_deg: float = 0.0) -> list:
    """All 8 inverse solutions of one pose -> list of 8 lists of 6 joint angles [deg].

    ``t`` is the 4x4 (or 3x4) target as nested sequences (mm).  A solution
    that does not exist is 6 NaN.  ``hint1_deg``/``hint4_deg`` are the
    robot's joint-1/joint-4 angles used at the shoulder/wrist singularities.
    """
    return ik_hinted(p, t, hint1_deg, hint4_deg)[0]


def ik_hinted(p: OpwParams, t, hint1_deg: float = 0.0, hint4_deg: float = 0.0) -> tuple[list, bool]:
    """:func:`ik`, and whether a hint was used (the pose is at a shoulder or wrist singularity).

    When no hint was used the solutions do not depend on the hints, so a
    caller may reuse them for the same pose with other hints.
    """
    r0, r1, r2 = t[0], t[1], t[2]
    r00, r02, px = r0[0], r0[2], r0[3]  # the middle column follows from the other two
    r10, r12, py = r1[0], r1[2], r1[3]
    r20, r22, pz = r2[0], r2[2], r2[3]
    c4m = p.c4
    cx = px - c4m * r02
    cy = py - c4m * r12
    cz = pz - c4m * r22
    b = p.b
    rr = cx * cx + cy * cy
    nx2 = rr - b * b
    out = [None] * 8
    nanrow = [NAN] * 6
    if not nx2 >= 0.0:  # also catches NaN input
        if nx2 > -1e-9 * max(1.0, b * b):
            nx2 = 0.0
        else:
            return [list(nanrow) for _ in range(8)], False
    nx = math.sqrt(nx2)
    sg, of = p.signs, p.offsets_deg
    hinted = False
    if b == 0.0 and rr < SHOULDER_EPS_MM * SHOULDER_EPS_MM:
        phi = (sg[0] * hint1_deg - of[0]) * RAD
        hinted = True
    else:
        phi = math.atan2(cy, cx)
    h4 = (sg[3] * hint4_deg - of[3]) * RAD
    g1, g2, g3, g4, g5, g6 = p._gain
    b1, b2, b3, b4, b5, b6 = p._bias
    c2l = p.c2
    k = p._k
    psi3 = p._psi3
    v = cz - p.c1
    den = 2.0 * c2l * k
    ck = c2l * c2l + k * k
    b5x2 = 2.0 * b5
    atan2, sin, cos, sqrt = math.atan2, math.sin, math.cos, math.sqrt
    if b == 0.0 and not hinted:
        # e^{i phi} from the WCP itself (no trig call)
        r = sqrt(rr)
        c1f, s1f = cx / r, cy / r
    else:
        c1f, s1f = cos(phi), sin(phi)
    for shoulder in (0, 1):
        x = nx if shoulder == 0 else -nx
        if b == 0.0:
            if shoulder == 0:
                q1, s1, c1 = phi, s1f, c1f
            else:
                q1, s1, c1 = phi + PI, -s1f, -c1f
        else:
            q1 = phi - atan2(b, x)
            s1, c1 = sin(q1), cos(q1)
        u = x - p.a1
        d = (u * u + v * v - ck) / den
        if d > 1.0 or d < -1.0:
            if d > 1.0 + ELBOW_EPS or d < -1.0 - ELBOW_EPS or d != d:
                for i in range(4):
                    out[4 * shoulder + i] = list(nanrow)
                continue
            d = 1.0 if d > 0 else -1.0
        acd = math.acos(d)
        sad = sqrt(1.0 - d * d)  # sin(acos d) >= 0
        atuv = atan2(u, v)
        delta = atan2(k * sad, c2l + k * d)  # elbow 0; elbow 1 is -delta
        # rotation rows of the target seen from the joint-1 plane
        p0 = c1 * r00 + s1 * r10
        p2 = c1 * r02 + s1 * r12
        o10 = -s1 * r00 + c1 * r10
        o12 = -s1 * r02 + c1 * r12
        # Deliberate copies: each joint angle is wrapped into (-180, 180] by the same
        # two loops written out inline (a helper call per angle costs ~2 us a pose).
        j1 = g1 * q1 + b1
        while j1 > 180.0:
            j1 -= 360.0
        while j1 <= -180.0:
            j1 += 360.0
        for elbow in (0, 1):
            if elbow == 0:
                q3 = acd - psi3
                q2 = atuv - delta
            else:
                q3 = -acd - psi3
                q2 = atuv + delta
            q23 = q2 + q3
            s23, c23 = sin(q23), cos(q23)
            # O = R_0c^T R (only the entries the ZYZ extraction needs)
            o00 = c23 * p0 - s23 * r20
            o20 = s23 * p0 + c23 * r20
            o02 = c23 * p2 - s23 * r22
            o22 = s23 * p2 + c23 * r22
            sb = sqrt(o02 * o02 + o12 * o12)
            beta = atan2(sb, o22)
            j2 = g2 * q2 + b2
            while j2 > 180.0:
                j2 -= 360.0
            while j2 <= -180.0:
                j2 += 360.0
            j3 = g3 * q3 + b3
            while j3 > 180.0:
                j3 -= 360.0
            while j3 <= -180.0:
                j3 += 360.0
            if sb > WRIST_EPS:
                alpha = atan2(o12, o02)
                ca, sa = o02 / sb, o12 / sb
            else:
                hinted = True
                alpha = h4
                ca, sa = cos(h4), sin(h4)
            w = ca * o00 + sa * o10
            m10 = -sa * o00 + ca * o10
            gamma = atan2(m10, o22 * w - sb * o20)
            j4 = g4 * alpha + b4
            while j4 > 180.0:
                j4 -= 360.0
            while j4 <= -180.0:
                j4 += 360.0
            j5 = g5 * beta + b5
            while j5 > 180.0:
                j5 -= 360.0
            while j5 <= -180.0:
                j5 += 360.0
            j6 = g6 * gamma + b6
            while j6 > 180.0:
                j6 -= 360.0
            while j6 <= -180.0:
                j6 += 360.0
            # wrist 1: (alpha + pi, -beta, gamma + pi); singular: alpha kept, gamma from the residual
            j5b = b5x2 - j5
            while j5b > 180.0:
                j5b -= 360.0
            while j5b <= -180.0:
                j5b += 360.0
            if sb > WRIST_EPS:
                # j - 180 of a tiny positive j rounds to -180: keep (-180, 180]
                j4b = j4 - 180.0 if j4 > 0.0 else j4 + 180.0
                if j4b == -180.0:
                    j4b = 180.0
                j6b = j6 - 180.0 if j6 > 0.0 else j6 + 180.0
                if j6b == -180.0:
                    j6b = 180.0
            else:
                j4b = j4
                j6b = g6 * atan2(m10, o22 * w + sb * o20) + b6
                while j6b > 180.0:
                    j6b -= 360.0
                while j6b <= -180.0:
                    j6b += 360.0
            base = 4 * shoulder + 2 * elbow
            out[base] = [j1, j2, j3, j4, j5, j6]
            out[base + 1] = [j1, j2, j3, j4b, j5b, j6b]
    return out, hinted
