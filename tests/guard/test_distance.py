"""The guard's distance primitives against brute force (issue 41; droid.guard.distance)."""
from __future__ import annotations

import numpy as np
import pytest

from droid.guard import distance as D


def _brute_segseg(p1, q1, p2, q2, n=801):
    s = np.linspace(0.0, 1.0, n)
    a = p1 + np.outer(s, q1 - p1)
    b = p2 + np.outer(s, q2 - p2)
    return float(np.min(np.linalg.norm(a[:, None] - b[None], axis=2)))


def test_segment_segment_matches_brute_force_and_known_cases():
    rng = np.random.default_rng(1)
    P = rng.uniform(-100, 100, size=(200, 4, 3))
    P[:20, 1] = P[:20, 0]  # points against segments
    P[20:30, 3] = P[20:30, 2]
    P[30:40, 3] = P[30:40, 2] + (P[30:40, 1] - P[30:40, 0])  # parallel segments
    d = D.segment_segment(P[:, 0], P[:, 1], P[:, 2], P[:, 3])
    ref = np.array([_brute_segseg(*p) for p in P])
    assert np.all(d <= ref + 1e-9)  # never more than a sampled pair of points
    assert np.max(ref - d) < 0.3  # the sampling's resolution (200 mm / 800)
    # crossing at right angles 10 mm apart; collinear disjoint; a point on a segment
    x = D.segment_segment(np.array([[-1.0, 0, 0], [0, 0, 0], [5.0, 0, 0]]), np.array([[1.0, 0, 0], [1, 0, 0], [5.0, 0, 0]]),
                          np.array([[0, -1.0, 10], [3, 0, 0], [0, 0, 0]]), np.array([[0, 1.0, 10], [4, 0, 0], [10, 0, 0]]))
    assert x == pytest.approx([10.0, 2.0, 0.0])


def _brute_segbox(p, q, h, n=2001):
    s = np.linspace(0.0, 1.0, n)
    return float(np.min(D.point_box(p + np.outer(s, q - p), h)))


def test_segment_box_matches_brute_force():
    rng = np.random.default_rng(2)
    h = rng.uniform(5, 60, size=(300, 3))
    p = rng.uniform(-150, 150, size=(300, 3))
    q = rng.uniform(-150, 150, size=(300, 3))
    d = D.segment_box(p, q, h)
    ref = np.array([_brute_segbox(p[i], q[i], h[i]) for i in range(300)])
    assert np.all(d <= ref + 1e-9)
    assert np.max(ref - d) < 0.1
    assert np.any(d == 0.0) and np.any(d > 0.0)  # both cases were drawn


def _rot(rng):
    A = rng.normal(size=(3, 3))
    Q, R = np.linalg.qr(A)
    return Q * np.sign(np.linalg.det(Q))


def test_box_box_matches_sampled_surfaces():
    rng = np.random.default_rng(3)
    n = 60
    ca, cb = rng.uniform(-80, 80, size=(n, 3)), rng.uniform(-80, 80, size=(n, 3))
    Ra, Rb = np.array([_rot(rng) for _ in range(n)]), np.array([_rot(rng) for _ in range(n)])
    ha, hb = rng.uniform(5, 40, size=(n, 3)), rng.uniform(5, 40, size=(n, 3))
    d = D.box_box(ca, Ra, ha, cb, Rb, hb)
    g = np.linspace(-1.0, 1.0, 25)
    grid = np.array(np.meshgrid(g, g, g)).reshape(3, -1).T
    for i in range(n):
        pts = ca[i] + (grid * ha[i]) @ Ra[i].T  # box a's volume, sampled
        local = (pts - cb[i]) @ Rb[i]
        ref = float(np.min(D.point_box(local, hb[i])))
        assert d[i] <= ref + 1e-9
        assert ref - d[i] < 0.1 * float(np.max(ha[i])) + 1e-9
