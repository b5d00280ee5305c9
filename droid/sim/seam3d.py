"""The seam in three dimensions: a sampled space curve with its surfaces (issue 15; docs/workpieces.md).

The thesis's workpieces (§6.1.1) are plane curves; :mod:`droid.sim.workpiece`
keeps its exact plane model for them.  A workpiece that climbs (``rise_mm``),
follows a free-form ``curve``, rolls along the seam (``roll_profile``), varies
its step (``step_profile``), or has ``[[gap]]``s and ``[[tack]]``s is a
:class:`Seam3D`: the seam's foot sampled every :data:`SAMPLE_MM` (or
finer) by arc length s [mm], each sample with its frame

* ``t`` the unit tangent (the direction of travel),
* ``n0`` the surface normal before roll (away from the surfaces, toward a sensor),
* ``l0 = n0 x t`` the left lateral before roll,

linear between samples, and extended along its end tangents before s = 0 and
after the end (as the plane model).  The roll r(s) turns the surface about
the tangent (right-handed about t: + lifts the left side): n = cos r n0 - sin r l0,
l = cos r l0 + sin r n0.

Surfaces (a lap joint, as the plane model): the lower surface runs from the
foot out to ``width_mm`` on the lower side, the upper one from ``step(s)``
above the foot (along n) out to ``width_mm`` on the upper side, with the
square edge face between; both are ruled surfaces S(s, u) = p(s) + u w(s)
(+ h n(s) for the upper one), w = -/+ upper_sign l(s).  In a gap the upper
surface comes down to the lower one (h = 0: no step, no feature); on a tack
the upper surface within :data:`TACK_WIDTH_MM` of the edge is raised by the
tack's height (a bump on the step).  Beyond ``-lead_in_mm`` and
``length + lead_out_mm`` along the seam there is no surface.

Renderers (each a pure function of a pose):

* :meth:`Seam3D.measure`: where the seam foot crosses a frame's x-y plane,
  seen from the frame (the tool-tip sensor and the ideal sensor);
* :meth:`Seam3D.stripe_depth_mm`: the camera twin's stripe, by intersecting
  the sensor's rays with the cross-section of both surfaces and the edge
  face in the laser sheet.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Alike in shape only to other numeric dataclasses (OpwParams): a reading, not geometry.
@dataclass(frozen=True)
class ToolReading:
    """Deviation of the seam from a sensor-like frame (:meth:`Seam3D.measure`; the tool-tip
    sensor's reading, droid.sim.mvs.tool_sensor): lateral and height offsets [mm] of the seam
    foot in the frame, the seam's roll about the frame's z [rad] and its arc length s [mm]."""

    lateral_mm: float
    height_mm: float
    roll_rad: float
    s_mm: float


#: Largest spacing [mm] of the samples along a curved piece (a 200 mm radius: 0.16 um chord error).
SAMPLE_MM = 0.5
#: Length [mm] of the straight extensions before the start and after the end.
EXTENSION_MM = 1.0e4
#: Width [mm] of a tack's bump on the upper surface, from the edge.
TACK_WIDTH_MM = 3.0
#: Lateral samples of each surface's cross-section in the laser sheet.
SECTION_SAMPLES = 25


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


class Seam3D:
    """A sampled seam with profiles, gaps and tacks (see the module docstring)."""

    def __init__(self, s_mm, p_mm, t, n0, *, step_mm: float, width_mm: float, upper_sign: float,
                 lead_in_mm: float, lead_out_mm: float, roll_profile=(), step_profile=(), gaps=(), tacks=()):
        s = np.asarray(s_mm, float)
        p = np.asarray(p_mm, float)
        t = _unit(np.asarray(t, float))
        n0 = np.asarray(n0, float)
        n0 = _unit(n0 - np.sum(n0 * t, axis=1, keepdims=True) * t)
        # what varies along the seam needs samples: every SAMPLE_MM when a profile varies, the
        # profiles' points, and both sides of each gap's and tack's ends (the step jumps there)
        edges = sorted({e for a, b in gaps for e in (a, b)} | {e for a, b, _ in tacks for e in (a, b)})
        points = [a for a, _ in roll_profile] + [a for a, _ in step_profile]
        dense = bool(roll_profile or step_profile)
        s, p, t, n0, s_eval = _refine(s, p, t, n0, dense, points, edges)
        self.length_mm = float(s[-1])
        # the straight extensions: one sample far before the start and one far after the end
        e = EXTENSION_MM
        self.s = np.concatenate([[s[0] - e], s, [s[-1] + e]])
        self.p = np.concatenate([[p[0] - e * t[0]], p, [p[-1] + e * t[-1]]])
        self.t = np.concatenate([[t[0]], t, [t[-1]]])
        self.n0 = np.concatenate([[n0[0]], n0, [n0[-1]]])
        self.step_mm = float(step_mm)
        self.width_mm = float(width_mm)
        self.upper_sign = float(upper_sign)
        self.along_mm = (-float(lead_in_mm), self.length_mm + float(lead_out_mm))
        self.roll_profile = tuple((float(a), float(b)) for a, b in roll_profile)  # (s_mm, roll_rad)
        self.step_profile = tuple((float(a), float(b)) for a, b in step_profile)  # (s_mm, step_mm)
        self.gaps = tuple((float(a), float(b)) for a, b in gaps)  # (s0, s1) [mm]
        self.tacks = tuple((float(a), float(b), float(h)) for a, b, h in tacks)  # (s0, s1, height) [mm]
        # per sample: the rolled frame and the step height (the profiles read at each sample;
        # at a jump, the sample pair reads either side)
        s_eval = np.concatenate([[s_eval[0] - e], s_eval, [s_eval[-1] + e]])
        roll = self.roll_at(s_eval)
        c, sn = np.cos(roll)[:, None], np.sin(roll)[:, None]
        l0 = np.cross(self.n0, self.t)
        self.n = c * self.n0 - sn * l0
        self.l = c * l0 + sn * self.n0
        self.h = self.step_at(s_eval)
        self.tack_h = self.tack_at(s_eval)

    # -- profiles along the seam ---------------------------------------------
    def roll_at(self, s_mm) -> np.ndarray:
        """Roll [rad] of the surfaces at arc length(s) s (linear between the profile's points)."""
        s = np.asarray(s_mm, float)
        if not self.roll_profile:
            return np.zeros_like(s)
        xs, ys = zip(*self.roll_profile)
        return np.interp(s, xs, ys)

    def step_at(self, s_mm) -> np.ndarray:
        """Step height [mm] at s: the profile's (or ``step_mm``), 0 in a gap."""
        s = np.asarray(s_mm, float)
        if self.step_profile:
            xs, ys = zip(*self.step_profile)
            h = np.interp(s, xs, ys)
        else:
            h = np.full_like(s, self.step_mm)
        for a, b in self.gaps:
            h = np.where((s >= a) & (s <= b), 0.0, h)
        return h

    def tack_at(self, s_mm) -> np.ndarray:
        """Height [mm] of a tack's bump at s (0 where there is none)."""
        s = np.asarray(s_mm, float)
        out = np.zeros_like(s)
        for a, b, height in self.tacks:
            out = np.where((s >= a) & (s <= b), np.maximum(out, height), out)
        return out

    def in_gap(self, s_mm: float) -> bool:
        """True where the seam has no feature (a gap)."""
        return any(a <= s_mm <= b for a, b in self.gaps)

    # -- frames ----------------------------------------------------------------
    def _locate(self, s_mm: float) -> tuple[int, float]:
        """Sample index i and fraction f with s between s[i] and s[i+1] (a turn: the later side)."""
        i = int(np.searchsorted(self.s, s_mm, side="right")) - 1
        i = min(max(i, 0), len(self.s) - 2)
        ds = self.s[i + 1] - self.s[i]
        return i, (0.0 if ds <= 0 else (s_mm - self.s[i]) / ds)

    def point_frame(self, s_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(p, t, n, l) at arc length s: the foot [mm] and the rolled frame (unit vectors), in W."""
        i, f = self._locate(float(s_mm))
        p = (1 - f) * self.p[i] + f * self.p[i + 1]
        t = _unit((1 - f) * self.t[i] + f * self.t[i + 1])
        n0 = (1 - f) * self.n0[i] + f * self.n0[i + 1]
        n0 = _unit(n0 - (n0 @ t) * t)
        l0 = np.cross(n0, t)
        r = float(self.roll_at(float(s_mm)))
        return p, t, math.cos(r) * n0 - math.sin(r) * l0, math.cos(r) * l0 + math.sin(r) * n0

    def seam_frame(self, s_mm: float) -> np.ndarray:
        """T_W_seam (4x4): origin on the foot, x = -n (into the surface), y = l (left), z = t."""
        p, t, n, l = self.point_frame(s_mm)
        out = np.eye(4)
        out[0:3, 0], out[0:3, 1], out[0:3, 2], out[0:3, 3] = -n, l, t, p
        return out

    # -- the seam crossing a plane ----------------------------------------------
    def crossing_s(self, T_W_F: np.ndarray) -> float | None:
        """Arc length [mm] where the foot crosses F's x-y plane, nearest to F's origin; None if nowhere."""
        o, z = T_W_F[0:3, 3], T_W_F[0:3, 2]
        f = (self.p - o) @ z
        a, b = f[:-1], f[1:]
        idx = np.nonzero(((a <= 0) & (b >= 0)) | ((a >= 0) & (b <= 0)))[0]
        if idx.size == 0:
            return None
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(a[idx] == b[idx], 0.0, a[idx] / (a[idx] - b[idx]))
        pts = self.p[idx] + frac[:, None] * (self.p[idx + 1] - self.p[idx])
        k = int(np.argmin(np.sum((pts - o) ** 2, axis=1)))
        return float(self.s[idx[k]] + frac[k] * (self.s[idx[k] + 1] - self.s[idx[k]]))

    def measure(self, T_W_F: np.ndarray):
        """The seam seen from frame F (tool_sensor.measure's reading), or None when it does not cross F's x-y plane."""
        t = np.asarray(T_W_F, float)
        s = self.crossing_s(t)
        if s is None:
            return None
        p, _, n, _ = self.point_frame(s)
        d = p - t[0:3, 3]
        R = t[0:3, 0:3]
        n_f = R.T @ n
        return ToolReading(lateral_mm=float(R[:, 1] @ d), height_mm=float(R[:, 0] @ d),
                           roll_rad=math.atan2(-float(n_f[1]), -float(n_f[0])), s_mm=float(s))

    # -- the camera's stripe -------------------------------------------------------
    def _section(self, T_W_S: np.ndarray, s_star: float, i_star: int, u: np.ndarray, upper: bool,
                 u_tack: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cross-section of one surface with S's x-y plane: (x, y) in S per lateral u, and valid."""
        o, R = T_W_S[0:3, 3], T_W_S[0:3, 0:3]
        z = R[:, 2]
        span = float(u[-1]) + 20.0
        lo = int(np.searchsorted(self.s, s_star - span, side="left"))
        hi = int(np.searchsorted(self.s, s_star + span, side="right"))
        lo, hi = max(lo - 1, 0), min(hi + 1, len(self.s))
        P, N, L = self.p[lo:hi], self.n[lo:hi], self.l[lo:hi]
        w = (self.upper_sign if upper else -self.upper_sign) * L  # lateral direction of this surface
        a = (P - o) @ z
        b = w @ z
        c = N @ z
        if upper:
            h = self.h[lo:hi][None, :] + np.where(u[:, None] < u_tack, self.tack_h[lo:hi][None, :], 0.0)
        else:
            h = np.zeros((1, hi - lo))
        F = a[None, :] + u[:, None] * b[None, :] + h * c[None, :]  # signed distance to the sheet (K, M)
        f0, f1 = F[:, :-1], F[:, 1:]
        change = ((f0 <= 0) & (f1 >= 0)) | ((f0 >= 0) & (f1 <= 0))
        j_star = i_star - lo
        dist = np.where(change, np.abs(np.arange(f0.shape[1])[None, :] - j_star), np.iinfo(np.int64).max)
        j = np.argmin(dist, axis=1)
        valid = change[np.arange(len(u)), j]
        rows = np.arange(len(u))
        g0, g1 = f0[rows, j], f1[rows, j]
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(g0 == g1, 0.0, g0 / (g0 - g1))
        hh = np.broadcast_to(h, F.shape)

        def at(k):
            return P[k] + u[:, None] * w[k] + hh[rows, k][:, None] * N[k]

        pts = at(j) * (1 - frac)[:, None] + at(j + 1) * frac[:, None]
        s_hit = self.s[lo + j] + frac * (self.s[lo + j + 1] - self.s[lo + j])
        valid &= (s_hit >= self.along_mm[0]) & (s_hit <= self.along_mm[1])
        d = pts - o
        return d @ R[:, 0], d @ R[:, 1], valid

    def stripe_depth_mm(self, T_W_S: np.ndarray, y_rows_mm: np.ndarray, standoff_mm: float) -> np.ndarray:
        """Depth x_S [mm] of the stripe on each row (rays along +x_S from -standoff; NaN = no stripe)."""
        t = np.asarray(T_W_S, float)
        y_rows = np.asarray(y_rows_mm, float)
        nan = np.full(len(y_rows), np.nan)
        s_star = self.crossing_s(t)
        if s_star is None:
            return nan
        _, _, n_star, _ = self.point_frame(s_star)
        if not float(n_star @ t[0:3, 0]) <= -1e-9:  # the laser does not point onto the surfaces' face
            return nan
        i_star, _ = self._locate(s_star)
        y_reach = float(np.max(np.abs(y_rows)))
        u_max = min(self.width_mm, 3.0 * y_reach + 10.0)  # beyond, no ray reaches (up to 70 deg of roll)
        u = np.linspace(0.0, u_max, SECTION_SAMPLES)
        u_tack = TACK_WIDTH_MM
        if self.tacks and 0 < u_tack < u_max:  # the bump's edge exactly: both sides of it
            u = np.sort(np.concatenate([u, [u_tack * (1 - 1e-9), u_tack]]))
        best = np.full(len(y_rows), np.inf)
        sections = [self._section(t, s_star, i_star, u, up, u_tack) for up in (False, True)]
        (xl, yl, vl), (xu, yu, vu) = sections
        # the edge face: from the foot (lower u = 0) to the top of the step (upper u = 0)
        face = (np.array([xl[0], xu[0]]), np.array([yl[0], yu[0]]), np.array([vl[0] and vu[0]] * 2))
        for x, y, v in ((xl, yl, vl), (xu, yu, vu), face):
            best = np.minimum(best, _rays_hit(x, y, v, y_rows, -standoff_mm))
        return np.where(np.isfinite(best), best, np.nan)


def _refine(s, p, t, n0, dense: bool, points, edges):
    """Samples added: every SAMPLE_MM (``dense``), at ``points``, and a pair at each of ``edges``.

    Returns (s, p, t, n0, s_eval): s_eval is s, but the first of a pair at an
    edge reads just before it and the second just after (gaps, tacks)."""
    eps = 1e-7
    inner = sorted(set(points) | set(edges))
    out_s, out_p, out_t, out_n, out_e = [s[0]], [p[0]], [t[0]], [n0[0]], [s[0]]

    def add(sv, pv, tv, nv, ev):
        out_s.append(sv), out_p.append(pv), out_t.append(tv), out_n.append(nv), out_e.append(ev)

    edge_set = set(edges)
    for i in range(len(s) - 1):
        a, b = s[i], s[i + 1]
        if b > a:
            extra = [v for v in inner if a < v < b]
            if dense:
                n = math.ceil((b - a) / SAMPLE_MM)
                extra = sorted(set(extra) | {a + (b - a) * k / n for k in range(1, n)})
            for v in extra:
                f = (v - a) / (b - a)
                pv = (1 - f) * p[i] + f * p[i + 1]
                tv = _unit((1 - f) * t[i] + f * t[i + 1])
                nv = (1 - f) * n0[i] + f * n0[i + 1]
                nv = _unit(nv - (nv @ tv) * tv)
                if v in edge_set:
                    add(v, pv, tv, nv, v - eps)
                    add(v, pv, tv, nv, v + eps)
                else:
                    add(v, pv, tv, nv, v)
        if s[i + 1] in edge_set and (i + 2 >= len(s) or s[i + 2] > s[i + 1]):
            add(s[i + 1], p[i + 1], t[i + 1], n0[i + 1], s[i + 1] - eps)
            add(s[i + 1], p[i + 1], t[i + 1], n0[i + 1], s[i + 1] + eps)
        else:
            add(s[i + 1], p[i + 1], t[i + 1], n0[i + 1], s[i + 1])
    return (np.array(out_s), np.array(out_p), np.array(out_t), np.array(out_n), np.array(out_e))


def _rays_hit(x: np.ndarray, y: np.ndarray, valid: np.ndarray, y_rows: np.ndarray, x_min: float) -> np.ndarray:
    """Nearest depth x (> x_min) where each row's ray (y = const) meets the polyline (x, y); inf if none."""
    ok = valid[:-1] & valid[1:]
    x0, x1, y0, y1 = x[:-1][ok], x[1:][ok], y[:-1][ok], y[1:][ok]
    if x0.size == 0:
        return np.full(len(y_rows), np.inf)
    yr = y_rows[:, None]
    lo, hi = np.minimum(y0, y1), np.maximum(y0, y1)
    inside = (yr >= lo) & (yr <= hi)
    dy = y1 - y0
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(dy != 0, (yr - y0) / dy, 0.0)
    xs = x0 + f * (x1 - x0)
    flat = dy == 0  # a segment along a ray: its nearer end
    xs = np.where(flat[None, :], np.minimum(x0, x1)[None, :], xs)
    xs = np.where(inside & (xs > x_min), xs, np.inf)
    return xs.min(axis=1)
