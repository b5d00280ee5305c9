"""A workpiece's surfaces as a small mesh for viewers (issue 29; docs/observe.md, docs/workpieces.md).

:func:`workpiece_mesh` samples the workpiece's own model (:class:`droid.sim.seam3d.Seam3D`, the
one the camera twin and the tool-tip sensor render) across the seam every
:data:`VIEW_STEP_MM` and at both sides of every gap's and tack's ends, and
returns plain JSON data in the workpiece frame W [mm]:

``{"name", "length_mm", "width_mm", "sections": N, "per_section": 6, "points": [x, y, z, ...],
"gap": [0|1] * N, "tack": [0|1] * N}``

Each section (one s, from ``-lead_in_mm`` to ``length + lead_out_mm``) is six points across the
lap joint, in order: the lower surface's outer edge, the seam's foot, the top of the edge face
(step + tack above the foot, along the rolled normal), the tack's strip on the upper surface
(:data:`~droid.sim.seam3d.TACK_WIDTH_MM` from the edge) raised and back down, and the upper
surface's outer edge.  Consecutive sections make five strips: lower surface, edge face, tack top,
tack side, upper surface.  So 3-D seams, rolled and climbing surfaces, a varying step, gaps
(the step comes down to nothing) and tacks are drawn from the same data the sensors see.

It lives in ``sim`` (the model's package); the observers, which may not import ``sim``
(docs/design.md §7), get it as data: a lockstep trial puts it in its recording's scene metadata.
"""
from __future__ import annotations

import numpy as np

from droid.sim.seam3d import TACK_WIDTH_MM

VIEW_STEP_MM = 5.0  # sections along the seam at most this far apart [mm]
EDGE_EPS_MM = 0.01  # sections this far either side of a gap's or tack's end [mm]
POINTS_PER_SECTION = 6


def section_s(seam, step_mm: float = VIEW_STEP_MM) -> np.ndarray:
    """Arc lengths [mm] of the sections: every ``step_mm`` over the surfaces, and both sides of the
    profiles' points and of every gap's and tack's end."""
    lo, hi = seam.along_mm
    n = max(2, int(np.ceil((hi - lo) / step_mm)) + 1)
    s = set(np.linspace(lo, hi, n).tolist())
    for a, b in seam.gaps:
        s |= {a - EDGE_EPS_MM, a + EDGE_EPS_MM, b - EDGE_EPS_MM, b + EDGE_EPS_MM}
    for a, b, _ in seam.tacks:
        s |= {a - EDGE_EPS_MM, a + EDGE_EPS_MM, b - EDGE_EPS_MM, b + EDGE_EPS_MM}
    s |= {a for a, _ in seam.roll_profile} | {a for a, _ in seam.step_profile}
    return np.array(sorted(v for v in s if lo <= v <= hi))


def workpiece_mesh(wp, step_mm: float = VIEW_STEP_MM) -> dict:
    """The surfaces of workpiece ``wp`` (a :class:`droid.sim.workpiece.Workpiece`) as sections of six
    points in W [mm] (see the module docstring)."""
    seam = wp.seam
    ss = section_s(seam, step_mm)
    pts = np.empty((len(ss), POINTS_PER_SECTION, 3))
    h = seam.step_at(ss)
    tk = seam.tack_at(ss)
    width = seam.width_mm
    tack_w = min(TACK_WIDTH_MM, width)
    for i, s in enumerate(ss):
        p, _, n, l = seam.point_frame(float(s))
        up = seam.upper_sign * l  # toward the upper surface
        top = p + (h[i] + tk[i]) * n
        pts[i] = (p - width * up, p, top, top + tack_w * up, p + h[i] * n + tack_w * up, p + h[i] * n + width * up)
    return {"name": wp.name, "length_mm": round(float(seam.length_mm), 3), "width_mm": float(width),
            "sections": int(len(ss)), "per_section": POINTS_PER_SECTION,
            "points": [round(float(v), 2) for v in pts.reshape(-1)],
            "gap": [int(v) for v in (h <= 0.0)], "tack": [int(v) for v in (tk > 0.0)]}
