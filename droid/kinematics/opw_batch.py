"""Batched (numpy) forms of the OPW kinematics in :mod:`droid.kinematics.opw`.

N poses or joint vectors at once, with no Python loop per pose; same
numbering, singularity policy and wrapping as the scalar forms, and equal to
them to rounding (tested).  Sines and cosines come from the geometry as
complex unit numbers (numpy's float64 sin/cos cost ~8 ns an element here,
arctan2 ~1.4 ns), and the inverse runs in chunks of :data:`BATCH_CHUNK` poses
so its temporaries stay in cache.
"""
from __future__ import annotations

import numpy as np

from .opw import ELBOW_EPS, PI, RAD, SHOULDER_EPS_MM, WRIST_EPS, OpwParams, wrap_scalar

def fk_batch(p: OpwParams, q_deg) -> np.ndarray:
    """Forward kinematics of joint vectors (N, 6) [deg] -> (N, 4, 4) [mm]."""
    q = np.asarray(q_deg, float)
    qo = (q * np.asarray(p.signs, float) - np.asarray(p.offsets_deg)) * RAD
    s = np.sin(qo)
    c = np.cos(qo)
    s1, c1 = s[:, 0], c[:, 0]
    s2, c2 = s[:, 1], c[:, 1]
    q23 = qo[:, 1] + qo[:, 2]
    s23, c23 = np.sin(q23), np.cos(q23)
    s4, c4 = s[:, 3], c[:, 3]
    s5, c5 = s[:, 4], c[:, 4]
    s6, c6 = s[:, 5], c[:, 5]
    n = q.shape[0]
    e = np.empty((n, 3, 3))
    e[:, 0, 0] = c4 * c5 * c6 - s4 * s6
    e[:, 0, 1] = -c4 * c5 * s6 - s4 * c6
    e[:, 0, 2] = c4 * s5
    e[:, 1, 0] = s4 * c5 * c6 + c4 * s6
    e[:, 1, 1] = -s4 * c5 * s6 + c4 * c6
    e[:, 1, 2] = s4 * s5
    e[:, 2, 0] = -s5 * c6
    e[:, 2, 1] = s5 * s6
    e[:, 2, 2] = c5
    u = c23[:, None] * e[:, 0, :] + s23[:, None] * e[:, 2, :]
    t = np.zeros((n, 4, 4))
    t[:, 0, :3] = c1[:, None] * u - s1[:, None] * e[:, 1, :]
    t[:, 1, :3] = s1[:, None] * u + c1[:, None] * e[:, 1, :]
    t[:, 2, :3] = -s23[:, None] * e[:, 0, :] + c23[:, None] * e[:, 2, :]
    cx1 = p.c2 * s2 + p.c3 * s23 + p.a2 * c23 + p.a1
    cz1 = p.c2 * c2 + p.c3 * c23 - p.a2 * s23
    t[:, 0, 3] = cx1 * c1 - p.b * s1 + p.c4 * t[:, 0, 2]
    t[:, 1, 3] = cx1 * s1 + p.b * c1 + p.c4 * t[:, 1, 2]
    t[:, 2, 3] = cz1 + p.c1 + p.c4 * t[:, 2, 2]
    t[:, 3, 3] = 1.0
    return t


def _wrap_inplace(y: np.ndarray) -> np.ndarray:
    """Wrap degrees in (-540, 540] into (-180, 180] in place (exact: Sterbenz)."""
    y -= 360.0 * (y > 180.0)
    y += 360.0 * (y <= -180.0)
    return y


#: poses per chunk in ik_batch (keeps temporaries in cache).
BATCH_CHUNK = 1024


def ik_batch(p: OpwParams, t, hint_deg=None, hint_used=None) -> np.ndarray:
    """All 8 inverse solutions of N poses (N, 4, 4) [mm] -> (N, 8, 6) [deg], NaN where none.

    ``hint_deg`` (6,) or (N, 6): joint angles [deg] whose joint 1 and joint 4
    are used at the shoulder and wrist singularities (default 0).  If
    ``hint_used`` is a bool array (N,), it is set True for the poses where a
    hint was used (a singular configuration).  Same numbering and policy as
    :func:`ik`.
    """
    t = np.asarray(t, float)
    n = t.shape[0]
    hint = None if hint_deg is None else np.broadcast_to(np.asarray(hint_deg, float), (n, 6))
    if hint_used is not None:
        hint_used[:] = False
    if n <= BATCH_CHUNK:
        return _ik_chunk(p, t, hint, hint_used)
    out = np.empty((n, 8, 6))
    for i in range(0, n, BATCH_CHUNK):
        j = min(n, i + BATCH_CHUNK)
        out[i:j] = _ik_chunk(
            p, t[i:j], None if hint is None else hint[i:j], None if hint_used is None else hint_used[i:j]
        )
    return out


def _ik_chunk(p: OpwParams, t, hint_deg=None, hint_used=None) -> np.ndarray:
    """All 8 inverse solutions of N poses (N, 4, 4) [mm] -> (N, 8, 6) [deg], NaN where none.

    ``hint_deg`` (6,) or (N, 6): joint angles [deg] whose joint 1 and joint 4
    are used at the shoulder and wrist singularities (default 0).
    Same numbering and policy as :func:`ik`.  Vectorised: sines and cosines
    come from the geometry (complex unit numbers), not from trig calls.
    Level by level, each once per chunk: the shoulder (:func:`_shoulder_level`), the arm
    (:func:`_arm_level`), the wrist (:func:`_wrist_level`), then :func:`_assemble`.
    """
    t = np.asarray(t, float)
    n = t.shape[0]
    out = np.empty((n, 8, 6))
    if n == 0:
        return out
    with np.errstate(invalid="ignore", divide="ignore"):
        q1, s1, c1, x, cz = _shoulder_level(p, t, hint_deg, hint_used)
        q2, q3, s23, c23 = _arm_level(p, x, cz)
        wrist = _wrist_level(p, t, s1, c1, s23, c23, hint_deg, hint_used)
        _assemble(p, out, q1, q2, q3, *wrist)
    return out


def _shoulder_level(p: OpwParams, t: np.ndarray, hint_deg, hint_used):
    """Joint 1 of the two shoulder solutions (N, 2) -- front, back -- from the wrist centre
    (the hint's joint 1 on the axis); its sine and cosine, the wrist centre's reach x in the
    joint-1 plane, and its height cz [mm]."""
    n = t.shape[0]
    sg = p.signs
    of = p.offsets_deg
    r02 = t[:, 0, 2]
    r12 = t[:, 1, 2]
    r22 = t[:, 2, 2]
    if p.c4 != 0.0:
        cx = t[:, 0, 3] - p.c4 * r02
        cy = t[:, 1, 3] - p.c4 * r12
        cz = t[:, 2, 3] - p.c4 * r22
    else:
        cx, cy, cz = t[:, 0, 3], t[:, 1, 3], t[:, 2, 3]
    rr = cx * cx + cy * cy
    nx2 = rr - p.b * p.b
    nx2[(nx2 < 0) & (nx2 > -1e-9 * max(1.0, p.b * p.b))] = 0.0
    nx = np.sqrt(nx2)  # NaN where the shoulder cannot reach (r < |b|)
    r = np.sqrt(rr)
    phi = np.arctan2(cy, cx)
    zphi = (cx + 1j * cy) / r  # e^{i phi}
    if p.b == 0.0:
        on_axis = rr < SHOULDER_EPS_MM * SHOULDER_EPS_MM
        if on_axis.any():
            hint = np.broadcast_to(
                np.zeros(6) if hint_deg is None else np.asarray(hint_deg, float), (n, 6)
            )
            ph = (sg[0] * hint[on_axis, 0] - of[0]) * RAD
            phi[on_axis] = ph
            zphi[on_axis] = np.exp(1j * ph)
            if hint_used is not None:
                hint_used |= on_axis
    x = np.empty((n, 2))
    x[:, 0] = nx
    x[:, 1] = -nx
    q1 = np.empty((n, 2))
    z1 = np.empty((n, 2), complex)
    if p.b == 0.0:
        q1[:, 0] = phi
        q1[:, 1] = phi + PI
        z1[:, 0] = zphi
        z1[:, 1] = -zphi
    else:
        zb = (x + 1j * p.b) / r[:, None]  # e^{i atan2(b, x)}
        q1[:] = phi[:, None] - np.arctan2(p.b, x)
        z1[:] = zphi[:, None] * zb.conj()
    return q1, z1.imag, z1.real, x, cz


def _arm_level(p: OpwParams, x: np.ndarray, cz: np.ndarray):
    """Joints 2 and 3 (N, 2, 2) in index order [shoulder][elbow], and sin/cos of q2 + q3: the
    triangle of c2 and k over the wrist centre (NaN elbow where it cannot close)."""
    n = x.shape[0]
    k = p._k
    c2 = p.c2
    u = x - p.a1
    v = (cz - p.c1)[:, None]
    rho2 = u * u + v * v
    d = (rho2 - (c2 * c2 + k * k)) / (2.0 * c2 * k)
    d[~(np.abs(d) <= 1.0 + ELBOW_EPS)] = np.nan
    np.clip(d, -1.0, 1.0, out=d)
    acd = np.arccos(d)
    sa = np.sqrt(1.0 - d * d)  # sin(acos d) >= 0
    rho = np.sqrt(rho2)
    atuv = np.arctan2(u, v)
    delta = np.arctan2(k * sa, c2 + k * d)  # shoulder angle of the triangle, elbow 0
    # e^{i(atuv - delta + acd)} for elbow 0; elbow 1 flips delta and acd
    zuv = (v + 1j * u) / rho
    zd = (c2 + k * d + 1j * (k * sa)) / rho
    zA = d + 1j * sa
    zpsi = (p.c3 - 1j * p.a2) / k
    # ---- arm level (N, 4) in index order [s0e0, s0e1, s1e0, s1e1]
    q2 = np.empty((n, 2, 2))
    q2[:, :, 0] = atuv - delta
    q2[:, :, 1] = atuv + delta
    q3 = np.empty((n, 2, 2))
    q3[:, :, 0] = acd - p._psi3
    q3[:, :, 1] = -acd - p._psi3
    z23 = np.empty((n, 2, 2), complex)
    zc = zuv * zpsi
    z23[:, :, 0] = zc * zd.conj() * zA
    z23[:, :, 1] = zc * zd * zA.conj()
    return q2, q3, z23.imag, z23.real


def _wrist_level(p: OpwParams, t: np.ndarray, s1, c1, s23, c23, hint_deg, hint_used):
    """The wrist's ZYZ angles (alpha, beta, gamma) (N, 2, 2) of O = R_0c^T R; at a singular
    wrist alpha is the hint's joint 4, and ``gb`` the residual gamma of branch 1 there.
    Returns alpha, beta, gamma, singular, any_singular, gb (None when no wrist is singular)."""
    n = t.shape[0]
    sg = p.signs
    of = p.offsets_deg
    r00, r02 = t[:, 0, 0], t[:, 0, 2]
    r10, r12 = t[:, 1, 0], t[:, 1, 2]
    r20, r22 = t[:, 2, 0], t[:, 2, 2]
    # target rotation seen from the joint-1 plane (N, 2) -> broadcast to (N, 2, 2)
    p0 = (c1 * r00[:, None] + s1 * r10[:, None])[:, :, None]
    p2 = (c1 * r02[:, None] + s1 * r12[:, None])[:, :, None]
    o10 = (-s1 * r00[:, None] + c1 * r10[:, None])[:, :, None]
    o12 = (-s1 * r02[:, None] + c1 * r12[:, None])[:, :, None]
    r20e = r20[:, None, None]
    r22e = r22[:, None, None]
    o00 = c23 * p0 - s23 * r20e
    o20 = s23 * p0 + c23 * r20e
    o02 = c23 * p2 - s23 * r22e
    o22 = s23 * p2 + c23 * r22e
    o12 = o12 + 0.0 * o02  # materialise (N, 2, 2)
    sb = np.sqrt(o02 * o02 + o12 * o12)
    beta = np.arctan2(sb, o22)
    alpha = np.arctan2(o12, o02)
    ca = o02 / sb
    sa_ = o12 / sb
    singular = sb <= WRIST_EPS
    any_singular = bool(singular.any())
    if any_singular:
        hint = np.broadcast_to(
            np.zeros(6) if hint_deg is None else np.asarray(hint_deg, float), (n, 6)
        )
        h4 = np.broadcast_to(((sg[3] * hint[:, 3] - of[3]) * RAD)[:, None, None], sb.shape)
        if hint_used is not None:
            hint_used |= singular.reshape(n, 4).any(axis=1)
        alpha[singular] = h4[singular]
        ca[singular] = np.cos(h4[singular])
        sa_[singular] = np.sin(h4[singular])
    w = ca * o00 + sa_ * o10
    m10 = ca * o10 - sa_ * o00
    gamma = np.arctan2(m10, o22 * w - sb * o20)
    # singular wrist: branch 1 keeps alpha, gamma from the residual
    gb = np.arctan2(m10[singular], (o22 * w + sb * o20)[singular]) if any_singular else None
    return alpha, beta, gamma, singular, any_singular, gb


def _assemble(p: OpwParams, out: np.ndarray, q1, q2, q3, alpha, beta, gamma, singular, any_singular, gb) -> None:
    """The joint angles in robot degrees into ``out`` (N, 8, 6) = (N, 2, 2, 2, 6)
    [shoulder][elbow][wrist]: gains, biases, wrapped into (-180, 180]; wrist branch 1 is
    (alpha + pi, -beta, gamma + pi); a NaN elbow makes the whole row NaN."""
    n = out.shape[0]
    g = p._gain
    bias = [wrap_scalar(b) for b in p._bias]
    o = out.reshape(n, 2, 2, 2, 6)
    j = g[0] * q1 + bias[0]
    o[..., 0] = _wrap_inplace(j)[:, :, None, None]
    j = g[1] * q2 + bias[1]
    o[..., 1] = _wrap_inplace(_wrap_inplace(j))[..., None]
    j = g[2] * q3 + bias[2]
    o[..., 2] = _wrap_inplace(_wrap_inplace(j))[..., None]
    j4 = _wrap_inplace(g[3] * alpha + bias[3])
    j5 = _wrap_inplace(g[4] * beta + bias[4])
    j6 = _wrap_inplace(g[5] * gamma + bias[5])
    o[:, :, :, 0, 3] = j4
    o[:, :, :, 0, 4] = j5
    o[:, :, :, 0, 5] = j6
    # wrist branch 1: (alpha + pi, -beta, gamma + pi)
    j4 += 180.0
    o[:, :, :, 1, 3] = _wrap_inplace(j4)
    j5 *= -1.0
    j5 += 2.0 * bias[4]
    o[:, :, :, 1, 4] = _wrap_inplace(_wrap_inplace(j5))
    j6 += 180.0
    o[:, :, :, 1, 5] = _wrap_inplace(j6)
    if any_singular:
        # singular wrist: branch 1 keeps alpha, gamma from the residual
        sel = o[:, :, :, 1, :]
        vals = sel[singular]
        vals[:, 3] = o[:, :, :, 0, 3][singular]
        vals[:, 5] = _wrap_inplace(g[5] * gb + bias[5])
        sel[singular] = vals
    # unreachable arm solutions (NaN elbow) -> whole row NaN
    bad = np.isnan(out[:, :, 2])
    if bad.any():
        out[bad] = np.nan
