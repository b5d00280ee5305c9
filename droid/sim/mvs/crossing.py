"""Where a sensor's laser sheet crosses the seam, in closed form (the tool-tip sensor's geometry, fast).

:func:`droid.sim.mvs.tool_sensor.measure` finds the seam point in a frame's x-y
plane (the laser sheet) by a damped Newton search over the arc length, with
a nearest-point search per step (~0.2 ms).  The seam is lines and circular
arcs in W's z = 0 plane, so the crossing has a closed form per segment:
linear in the arc length on a line, ``A cos(phi) + B sin(phi) = K`` on an
arc.  :class:`SeamCrossing` solves those (scalar math, ~15 us) and returns
the same :class:`~droid.sim.mvs.tool_sensor.ToolReading`: of several crossings
the one nearest to the frame's origin (a test checks it against ``measure``).
"""
from __future__ import annotations

import math

import numpy as np

from droid.sim.mvs.tool_sensor import ToolReading
from droid.sim.workpiece import Workpiece

_EPS = 1e-12


class SeamCrossing:
    """Closed-form ``measure`` for one workpiece (seam and its straight extensions)."""

    def __init__(self, workpiece: Workpiece) -> None:
        self.workpiece = workpiece
        self._seam3d = None if workpiece.planar else workpiece.seam  # a 3-D seam (issue 15): sampled
        self._segs = []
        for seg in workpiece._all:  # the seam's segments and the two straight extensions
            h = seg.heading0_rad
            cx, cy = math.cos(h), math.sin(h)
            sx, sy = (float(v) for v in seg.start_xy)
            if not seg.is_arc:
                self._segs.append(("line", seg.s0_mm, seg.length_mm, sx, sy, cx, cy))
            else:
                sign = 1.0 if seg.sweep_rad > 0 else -1.0
                r = seg.radius_mm
                ccx, ccy = sx - sign * r * cy, sy + sign * r * cx
                self._segs.append(("arc", seg.s0_mm, abs(seg.sweep_rad), ccx, ccy, r, sign, h - sign * math.pi / 2))

    def crossings(self, T_W_F: np.ndarray) -> list[tuple[float, float, float]]:
        """All crossings (s [mm], x, y in W) of the frame's x-y plane with the seam."""
        t = T_W_F
        zx, zy, zz = float(t[0, 2]), float(t[1, 2]), float(t[2, 2])
        ox, oy, oz = float(t[0, 3]), float(t[1, 3]), float(t[2, 3])
        a0 = -(zx * ox + zy * oy + zz * oz)  # z_F of a W point p (p_z = 0): zx px + zy py + a0
        out = []
        for seg in self._segs:
            if seg[0] == "line":
                _, s0, length, sx, sy, cx, cy = seg
                b = zx * cx + zy * cy
                if abs(b) < _EPS:
                    continue
                u = -(zx * sx + zy * sy + a0) / b
                if -1e-9 <= u <= length + 1e-9:
                    out.append((s0 + u, sx + u * cx, sy + u * cy))
            else:
                _, s0, sweep, ccx, ccy, r, sign, phi0 = seg
                a, b = zx * r, zy * r
                k = -(zx * ccx + zy * ccy + a0)
                m = math.hypot(a, b)
                if m < _EPS or abs(k) > m:
                    continue
                base, d = math.atan2(b, a), math.acos(max(-1.0, min(1.0, k / m)))
                for phi in (base + d, base - d):
                    theta = (sign * (phi - phi0)) % (2 * math.pi)
                    if theta <= sweep + 1e-12:
                        out.append((s0 + r * theta, ccx + r * math.cos(phi), ccy + r * math.sin(phi)))
        return out

    def measure(self, T_W_F: np.ndarray) -> ToolReading | None:
        """Deviation of the seam seen from frame F (as tool_sensor.measure), or None (no crossing)."""
        if self._seam3d is not None:
            return self._seam3d.measure(T_W_F)
        found = self.crossings(T_W_F)
        if not found:
            return None
        t = T_W_F
        ox, oy, oz = float(t[0, 3]), float(t[1, 3]), float(t[2, 3])
        s, px, py = min(found, key=lambda c: (c[1] - ox) ** 2 + (c[2] - oy) ** 2 + oz * oz)
        dx, dy, dz = px - ox, py - oy, -oz
        height = float(t[0, 0] * dx + t[1, 0] * dy + t[2, 0] * dz)  # F's x: depth
        lateral = float(t[0, 1] * dx + t[1, 1] * dy + t[2, 1] * dz)  # F's y
        roll = math.atan2(-float(t[2, 1]), -float(t[2, 0]))  # the W normal (+z) in F: (t20, t21, t22)
        return ToolReading(lateral_mm=lateral, height_mm=height, roll_rad=roll, s_mm=float(s))
