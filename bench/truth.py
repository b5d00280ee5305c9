"""Reading a standstill off the world's truth (the benches' common measure; docs/benchmarks.md)."""
from __future__ import annotations

import numpy as np


def standstill(pts: list[tuple[int, np.ndarray]], after_ns: int, tol_mm: float = 0.01,
               hold_ns: int = 200_000_000) -> int | None:
    """The first truth sample ``(t_ns, position_mm)`` at or after ``after_ns`` from which the
    position stays within ``tol_mm`` for ``hold_ns`` (None if the record ends first)."""
    pts = [(t, p) for t, p in pts if t >= after_ns]
    for i, (t, p) in enumerate(pts):
        if pts[-1][0] < t + hold_ns:
            return None
        if all(np.max(np.abs(q - p)) <= tol_mm for u, q in pts[i:] if u <= t + hold_ns):
            return t
    return None
