"""The seam map of plus mode (issue 12 item 3): the seam in the workpiece frame, from stamped readings.

The map lives in the workpiece holder's wrist-centre frame ``(GMF1)6`` (the
workpiece is fixed to it, §5.1), so it stays true when the holder moves.
Every valid lead reading, placed with the robots' poses *of its own capture
instant* (droid.tasks.seam.cycle), gives one seam point and the surface
normal there (the seam frame's x axis: toward the surface, rolled by the
reading's roll).  The map keeps them as knots along an arc length ``s`` [mm]:

* **outlier rejection**: a new point further than ``reject_mm`` from the
  map's quadratic extrapolation is held back; ``confirm`` consecutive held
  points that agree with each other are a real change of the seam (a corner)
  and enter; a lone one is dropped and counted (``rejected``);
* **a local smooth fit** (:meth:`SeamMap.fit`): a weighted least-squares
  quadratic in ``s`` over the knots within ``window_mm`` gives position,
  unit tangent, curvature vector and the surface normal (the knots' mean
  normal, made orthogonal to the tangent) -- the roll is the normal's turn
  about the tangent;
* **gaps bridged**: between knots further apart than the window, and up to
  ``gap_mm`` beyond the newest knot, the fit is extended (linear between two
  knots, the front's quadratic beyond it); further than that the map has no
  answer (``None``) and the tracker stops ("seam lost").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Fit window half-width [mm] (at least WINDOW_KNOTS knots' spacing).
WINDOW_MM = 6.0
WINDOW_KNOTS = 3
#: A new point further than this from the map's prediction is held back [mm].
REJECT_MM = 1.0
#: Held-back points that agree with each other enter after this many in a row.
CONFIRM = 3
#: Largest curvature the map extrapolates with [1/mm] (R20).
MAX_CURVATURE = 1.0 / 20.0
#: Points closer than this along the seam to the newest knot are merged into it [mm].
MIN_SPACING_MM = 0.05


@dataclass(frozen=True)
class SeamPoint:
    """The map at one arc length: position [mm], unit tangent, curvature vector [1/mm], unit normal."""

    s_mm: float
    p: np.ndarray
    t: np.ndarray
    k: np.ndarray
    n: np.ndarray


class SeamMap:
    """Knots (s, position, normal) in the holder's wrist frame; see the module docstring."""

    def __init__(self, window_mm: float = WINDOW_MM, reject_mm: float = REJECT_MM, confirm: int = CONFIRM,
                 gap_mm: float = 30.0) -> None:
        self.window_mm = float(window_mm)
        self.reject_mm = float(reject_mm)
        self.confirm = int(confirm)
        self.gap_mm = float(gap_mm)
        self._s = np.zeros(1024)
        self._p = np.zeros((1024, 3))
        self._n = np.zeros((1024, 3))
        self._w = np.zeros(1024)  # merged points per knot
        self.size = 0
        self.rejected = 0
        self._held: list[tuple[np.ndarray, np.ndarray]] = []
        self._first_reading_s: float | None = None
        self.version = 0  # bumped on every change of the knots
        self._front_cache: tuple[int, SeamPoint] | None = None

    # -- building ----------------------------------------------------------------
    @property
    def front_s(self) -> float:
        return float(self._s[self.size - 1]) if self.size else 0.0

    @property
    def first_reading_s(self) -> float | None:
        """Arc length of the first sensed knot (the seed is the tool's start point)."""
        return self._first_reading_s

    def seed(self, p, n, t=(0.0, 0.0, 1.0)) -> None:
        """The first knot: the tool's start point (the initial straight section, §6.1.1), with the
        tool's travel direction ``t`` as the tangent until a second knot exists."""
        self._seed_t = np.asarray(t, float) / max(float(np.linalg.norm(t)), 1e-12)
        self._append(0.0, np.asarray(p, float), np.asarray(n, float))

    def _append(self, s: float, p: np.ndarray, n: np.ndarray) -> None:
        if self.size == len(self._s):
            grow = len(self._s)
            self._s = np.concatenate([self._s, np.zeros(grow)])
            self._p = np.concatenate([self._p, np.zeros((grow, 3))])
            self._n = np.concatenate([self._n, np.zeros((grow, 3))])
            self._w = np.concatenate([self._w, np.zeros(grow)])
        i = self.size
        self._s[i], self._p[i], self._n[i], self._w[i] = s, p, n / max(np.linalg.norm(n), 1e-12), 1.0
        self.size += 1
        self.version += 1

    def add(self, p, n) -> bool:
        """Add a sensed seam point ``p`` with its surface normal ``n``; False if held back or dropped."""
        p, n = np.asarray(p, float), np.asarray(n, float)
        if self.size == 0:
            self.seed(p, n)
            return True
        front = self.front()
        d = p - front.p
        ds = float(d @ front.t)
        if self.size >= 2 * WINDOW_KNOTS and self._first_reading_s is not None:
            pred = front.p + front.t * ds + 0.5 * front.k * ds * ds
            if float(np.linalg.norm(p - pred)) > self.reject_mm:
                self._held.append((p, n))
                if len(self._held) < self.confirm:
                    return False
                pts = np.array([h[0] for h in self._held])
                span = pts[-1] - pts[0]
                L = float(np.linalg.norm(span))
                mid = pts[1:-1] - pts[0]
                off = mid - np.outer(mid @ span, span) / max(L * L, 1e-12) if L > 1e-9 else mid
                if L > 1e-9 and float(np.abs(off).max(initial=0.0)) <= self.reject_mm / 2:
                    held, self._held = self._held, []  # they agree: the seam has changed, take them
                    for hp, hn in held:
                        self._enter(hp, hn, front)
                    return True
                self.rejected += 1  # the oldest held point was a lone outlier
                self._held.pop(0)
                return False
        self.rejected += len(self._held)  # a point that fits: whatever was held back was spurious
        self._held = []
        self._enter(p, n, front)
        return True

    def _enter(self, p: np.ndarray, n: np.ndarray, front: SeamPoint) -> None:
        i = self.size - 1
        ds = float((p - self._p[i]) @ front.t)
        if self._first_reading_s is None:
            ds = float(np.linalg.norm(p - self._p[i]))
        if ds < MIN_SPACING_MM:  # no progress along the seam: merge into the newest knot
            if self._first_reading_s is None or i == 0:
                return
            w = self._w[i]
            self._p[i] = (self._p[i] * w + p) / (w + 1)
            self._n[i] = (self._n[i] * w + n) / (w + 1)
            self._w[i] = w + 1
            self.version += 1
            return
        self._append(self.front_s + ds, p, n)
        if self._first_reading_s is None:
            self._first_reading_s = self.front_s

    # -- reading -----------------------------------------------------------------
    def fit(self, s: float, one_sided: bool = False, wide: float = 1.0) -> SeamPoint | None:
        """The map at arc length ``s`` (see the module docstring); None beyond the bridged gap.

        The quadratic fit needs knots covering the whole window (a short stretch of noisy
        points gives no tangent); where they do not -- the initial section, a gap, the first
        millimetres of sensed seam -- the map is the straight line between the knots about
        ``s``.  Beyond the newest knot: the front's fit over twice the window, extended with
        its tangent and curvature."""
        n = self.size
        if n == 0:
            return None
        S = self._s[:n]
        if s > S[-1] + self.gap_mm:
            return None
        if n == 1:
            t = getattr(self, "_seed_t", np.array([0.0, 0.0, 1.0]))
            return SeamPoint(s, self._p[0] + t * s, t.copy(), np.zeros(3), _normal(self._n[0], t))
        if s > S[-1]:
            return self._extrapolate(s)
        span = wide * max(self.window_mm, WINDOW_KNOTS * (S[-1] - S[max(0, n - 8)]) / max(1, min(7, n - 1)))
        lo = int(np.searchsorted(S, s - span, "left"))
        hi = int(np.searchsorted(S, s + span, "right"))
        need = min(span, S[-1] - s + span) if not one_sided else span
        if hi - lo < 2 * WINDOW_KNOTS or S[hi - 1] - S[lo] < 0.9 * need:  # sparse: the line between knots
            j = int(np.clip(np.searchsorted(S, s), 1, n - 1))
            i0 = j - 1
            while i0 > 0 and S[j] - S[i0] < span:  # a baseline of at least the window
                i0 -= 1
            a, b = self._p[i0], self._p[j]
            L = max(S[j] - S[i0], 1e-9)
            t = (b - a) / max(np.linalg.norm(b - a), 1e-12)
            u = (s - S[i0]) / L
            nn = self._n[i0] * (1 - u) + self._n[j] * u if 0 <= u <= 1 else (self._n[j] if u > 1 else self._n[i0])
            return SeamPoint(s, a + (b - a) * u, t, np.zeros(3), _normal(nn, t))
        u = S[lo:hi] - s
        w = np.maximum(1.0 - np.abs(u) / (span * 1.0001), 0.05) * self._w[lo:hi]
        A = np.stack([np.ones_like(u), u, u * u], axis=1)
        Aw = A * w[:, None]
        coef, *_ = np.linalg.lstsq(Aw.T @ A, Aw.T @ self._p[lo:hi], rcond=None)
        p0, d1, d2 = coef[0], coef[1], 2.0 * coef[2]
        sp = max(float(np.linalg.norm(d1)), 1e-9)
        t = d1 / sp
        k = (d2 - t * float(d2 @ t)) / (sp * sp)
        nn = (self._n[lo:hi] * w[:, None]).sum(axis=0)
        return SeamPoint(s, p0, t, k, _normal(nn, t))

    def normal(self, s: float, half_mm: float, t) -> np.ndarray:
        """The surface normal at ``s`` averaged over the knots within ``half_mm`` of it (triangular
        weights), made orthogonal to the tangent ``t``: the seam's roll, spatially smoothed.  The
        readings' roll is the noisiest thing they carry (a few tenths of a degree from the line
        fits, plus the deflection of the arm that carried the sensor), and the tool's orientation
        must not chase it (plus mode, docs/seamtrack.md "On the full arm")."""
        n = self.size
        S = self._s[:n]
        lo = int(np.searchsorted(S, s - half_mm, "left"))
        hi = int(np.searchsorted(S, s + half_mm, "right"))
        if hi - lo < 1:
            j = int(np.clip(np.searchsorted(S, s), 0, n - 1))
            lo, hi = j, j + 1
        w = np.maximum(1.0 - np.abs(S[lo:hi] - s) / (half_mm * 1.0001), 0.05) * self._w[lo:hi]
        return _normal((self._n[lo:hi] * w[:, None]).sum(axis=0), np.asarray(t, float))

    def front(self) -> SeamPoint:
        """The fit at the newest knot over twice the window (cached until the knots change)."""
        c = self._front_cache
        if c is None or c[0] != self.version:
            c = self._front_cache = (self.version, self.fit(self.front_s, one_sided=True, wide=2.0))
        return c[1]

    def _extrapolate(self, s: float) -> SeamPoint:
        f = self.front()
        u = s - f.s_mm
        k = f.k
        kn = float(np.linalg.norm(k))
        if kn > MAX_CURVATURE:
            k = k * (MAX_CURVATURE / kn)
        t = f.t + k * u
        t = t / max(np.linalg.norm(t), 1e-12)
        return SeamPoint(s, f.p + f.t * u + 0.5 * k * u * u, t, k, _normal(f.n, t))

    def project(self, p, s_guess: float) -> float:
        """Arc length of the map point nearest ``p``, searched about ``s_guess`` [mm]."""
        s = float(s_guess)
        for _ in range(3):
            f = self.fit(min(s, self.front_s + self.gap_mm))
            if f is None:
                return s
            s = f.s_mm + float((np.asarray(p, float) - f.p) @ f.t)
        return s


def _normal(n: np.ndarray, t: np.ndarray) -> np.ndarray:
    n = n - t * float(n @ t)
    return n / max(float(np.linalg.norm(n)), 1e-12)


def chord_point(m: SeamMap, s0: float, p0: np.ndarray, length_mm: float,
                farthest: bool = False) -> SeamPoint | None:
    """The map point a straight ``length_mm`` from ``p0`` (the map at ``s0``), further along; None
    when the map (with its bridged gap) does not reach that far -- or, with ``farthest``, then the
    point of the reachable map farthest from ``p0`` (sampled every 1 mm of arc length from
    ``s0 + length_mm``; None only when the map ends at ``s0``).  On a tight arc the whole mapped seam, its extrapolation
    included, can lie nearer than ``length_mm``: the extrapolation with the arc's curvature bends
    back toward ``p0`` (plus mode's sensor aim, docs/seamtrack.md "The R25 arc")."""
    lo, hi = s0, min(s0 + length_mm * 1.6, m.front_s + m.gap_mm)
    f_hi = m.fit(hi) if hi > lo else None
    if f_hi is None or float(np.linalg.norm(f_hi.p - p0)) < length_mm:
        if not farthest or hi <= lo:
            return None
        best, best_d = None, -1.0
        start = min(lo + length_mm, hi)  # no chord is longer than its arc
        for s in np.arange(start, hi + 0.5, 1.0):
            f = m.fit(float(min(s, hi)))
            d = -1.0 if f is None else float(np.linalg.norm(f.p - p0))
            if d >= length_mm:  # the chord's end lies within the last sample: the bisection below
                lo, hi = max(lo, float(s) - 1.0), float(min(s, hi))
                break
            if d > best_d:
                best, best_d = f, d
        else:
            return best
    for _ in range(30):
        mid = (lo + hi) / 2
        f = m.fit(mid)
        if f is None or float(np.linalg.norm(f.p - p0)) > length_mm:
            hi = mid
        else:
            lo = mid
        if hi - lo < 0.05:
            break
    return m.fit(hi)

