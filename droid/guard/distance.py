"""Vectorised distances between capsules and boxes [mm] (issue 41; docs/guard.md).

Every function takes arrays of N pairs and returns N distances, so one call of numpy
serves every pair of a cell.  Lengths are in mm.

* :func:`segment_segment` -- the distance between two segments (Ericson, *Real-Time
  Collision Detection* §5.1.9: the closest points by clamping the line parameters);
  a capsule pair's distance is it minus both radii, exact also when they overlap
  (then it is minus the penetration depth).
* :func:`segment_box` -- the distance between a segment and an axis-aligned box centred
  at the origin (half sizes ``h``): 0 if the segment enters the box (slab clipping),
  else the least of the endpoints' distances to the box and the segment's distances to
  the box's 12 edges.  That is exact: if the closest point of the segment is inside it
  and the closest point of the box is inside a face, the segment is parallel to the
  face, and sliding along it reaches an endpoint or the face's edge at the same
  distance.
* :func:`box_box` -- two boxes: the least of every edge of each against the other box
  (:func:`segment_box` with radius 0), exact by the same argument (a closest pair of
  features always has an edge of one of the boxes; every vertex of an overlap lies on
  an edge of one box inside the other), 0 when they overlap.

A pair with a box that overlaps has no penetration depth here: its distance is
``-radius`` (capsule-box) or 0 (box-box) and the caller flags it as in collision
(:data:`OVERLAP_MM`); only capsule pairs give exact negative distances.
"""
from __future__ import annotations

import numpy as np

#: a distance at or below this [mm] is "in collision" (touching counts)
OVERLAP_MM = 0.0
_EPS = 1e-12

#: the 12 edges of the unit box [-1, 1]^3 as (start, end) corner signs: (12, 2, 3)
_CORNERS = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
_EDGE_IDX = [(a, b) for a in range(8) for b in range(a + 1, 8)
             if np.count_nonzero(_CORNERS[a] != _CORNERS[b]) == 1]
UNIT_BOX_EDGES = np.array([[_CORNERS[a], _CORNERS[b]] for a, b in _EDGE_IDX])


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def segment_segment(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Distances [mm] between segments p1-q1 and p2-q2 (arrays (..., 3)); zero-length segments are points."""
    return segment_segment_points(p1, q1, p2, q2)[0]


def segment_segment_points(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray,
                           q2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`segment_segment` with its closest points: (distance, point on p1-q1, point on p2-q2)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    c, b = _dot(d1, r), _dot(d1, d2)
    a_ok, e_ok = a > _EPS, e > _EPS
    a_safe, e_safe = np.where(a_ok, a, 1.0), np.where(e_ok, e, 1.0)
    denom = a * e - b * b
    s = np.where(denom > _EPS * np.maximum(a * e, 1.0), np.clip((b * f - c * e) / np.where(denom > 0, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_safe
    # t outside [0, 1]: clamp it and recompute s for the clamped t
    s = np.where(t < 0.0, np.clip(-c / a_safe, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a_safe, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # degenerate segments: a point (a = 0) against a segment, or two points
    s = np.where(a_ok, s, 0.0)
    t = np.where(a_ok, t, np.clip(f / e_safe, 0.0, 1.0))
    s = np.where(e_ok, s, np.where(a_ok, np.clip(-c / a_safe, 0.0, 1.0), 0.0))
    t = np.where(e_ok, t, 0.0)
    c1, c2 = p1 + d1 * s[..., None], p2 + d2 * t[..., None]
    diff = c1 - c2
    return np.sqrt(_dot(diff, diff)), c1, c2


def point_box(p: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Distances [mm] of points p (..., 3) to origin-centred axis-aligned boxes of half sizes h (0 inside)."""
    g = np.maximum(np.abs(p) - h, 0.0)
    return np.sqrt(_dot(g, g))


def _slabs(p: np.ndarray, q: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slab clipping of segments p-q (..., 3) against origin-centred boxes of half sizes h: each
    axis's entry and exit parameters (lo, hi; -inf / inf where the segment runs along the slab)
    and where it does (``small``)."""
    d = q - p
    small = np.abs(d) < _EPS
    d_safe = np.where(small, 1.0, d)
    t0 = (-h - p) / d_safe
    t1 = (h - p) / d_safe
    lo = np.where(small, -np.inf, np.minimum(t0, t1))
    hi = np.where(small, np.inf, np.maximum(t0, t1))
    return lo, hi, small


def segment_enters_box(p: np.ndarray, q: np.ndarray, h: np.ndarray) -> np.ndarray:
    """True where segment p-q (..., 3) meets the origin-centred box of half sizes h (slab clipping)."""
    lo, hi, small = _slabs(p, q, h)
    inside_slab = np.where(small, np.abs(p) <= h, True)
    tmin = np.maximum(lo.max(axis=-1), 0.0)
    tmax = np.minimum(hi.min(axis=-1), 1.0)
    return (tmin <= tmax) & inside_slab.all(axis=-1)


def segment_box(p: np.ndarray, q: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Distances [mm] of segments p-q (N, 3), in each box's frame, to origin-centred boxes of half sizes h (N, 3)."""
    edges = UNIT_BOX_EDGES[None, :, :, :] * h[:, None, None, :]  # (N, 12, 2, 3)
    d_edges = segment_segment(p[:, None, :], q[:, None, :], edges[:, :, 0, :], edges[:, :, 1, :]).min(axis=1)
    d = np.minimum(np.minimum(point_box(p, h), point_box(q, h)), d_edges)
    return np.where(segment_enters_box(p, q, h), 0.0, d)


def segment_entry(p: np.ndarray, q: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The slab clipping's entry parameter t in [0, 1] of segments p-q (..., 3) into origin-centred
    boxes (meaningful where :func:`segment_enters_box`): its point p + t (q - p) is in the box."""
    lo = _slabs(p, q, h)[0]
    return np.minimum(np.maximum(lo.max(axis=-1), 0.0), 1.0)


def segment_box_points(p: np.ndarray, q: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`segment_box` with its closest points, in the box's frame: (distance, point on the
    segment, point of the box).  The candidates in this order -- endpoint p, endpoint q, the 12
    edges (UNIT_BOX_EDGES') -- the first least one wins (the compiled pass breaks ties alike); a
    segment that enters the box gives 0 and its entry point twice (no direction: docs/guard.md §5)."""
    edges = UNIT_BOX_EDGES[None, :, :, :] * h[:, None, None, :]  # (N, 12, 2, 3)
    d_e, c_s, c_e = segment_segment_points(p[:, None, :], q[:, None, :], edges[:, :, 0, :], edges[:, :, 1, :])
    cand_d = np.concatenate([point_box(p, h)[:, None], point_box(q, h)[:, None], d_e], axis=1)  # (N, 14)
    cand_s = np.concatenate([p[:, None], q[:, None], c_s], axis=1)  # (N, 14, 3)
    cand_b = np.concatenate([np.clip(p, -h, h)[:, None], np.clip(q, -h, h)[:, None], c_e], axis=1)
    k = np.argmin(cand_d, axis=1)
    n = np.arange(p.shape[0])
    d, cs, cb = cand_d[n, k], cand_s[n, k], cand_b[n, k]
    inside = segment_enters_box(p, q, h)
    entry = p + segment_entry(p, q, h)[:, None] * (q - p)
    cs = np.where(inside[:, None], entry, cs)
    return np.where(inside, 0.0, d), cs, np.where(inside[:, None], entry, cb)


def to_box_frame(points: np.ndarray, centre: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Points (N, ..., 3) in the frames of boxes with centres (N, 3) and rotations (N, 3, 3) (columns: box axes)."""
    rel = points - centre.reshape(centre.shape[0], *([1] * (points.ndim - 2)), 3)
    return np.einsum("nji,n...j->n...i", R, rel)


def box_edges(centre: np.ndarray, R: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The 12 edges (N, 12, 2, 3) of boxes (centres (N, 3), rotations (N, 3, 3), half sizes (N, 3))."""
    local = UNIT_BOX_EDGES[None] * h[:, None, None, :]
    return centre[:, None, None, :] + np.einsum("nij,nkej->nkei", R, local)


def box_box(ca: np.ndarray, Ra: np.ndarray, ha: np.ndarray, cb: np.ndarray, Rb: np.ndarray, hb: np.ndarray) -> np.ndarray:
    """Distances [mm] between boxes a and b (N each; 0 where they overlap)."""
    n = ca.shape[0]
    out = []
    for (c1, R1, h1), (c2, R2, h2) in (((ca, Ra, ha), (cb, Rb, hb)), ((cb, Rb, hb), (ca, Ra, ha))):
        e = to_box_frame(box_edges(c1, R1, h1), c2, R2)  # (N, 12, 2, 3) in box 2's frame
        hh = np.repeat(h2, 12, axis=0)
        out.append(segment_box(e[:, :, 0].reshape(-1, 3), e[:, :, 1].reshape(-1, 3), hh).reshape(n, 12).min(axis=1))
    return np.minimum(out[0], out[1])
