"""The seam tracker's nearest-segment search compiled, for lockstep trials (issue 44).

The thesis-mode tracker (droid.tasks.seam.core.SeamTracker.interpolate_thesis) projects the tool
point onto every segment of its seam patch each 30 Hz cycle: at 1.5 mm/s the patch from the
camera to the tool holds ~2000 frames, and the numpy expressions of
:func:`droid.tasks.seam.core.nearest_segment` were the largest single cost of a slow trial.
``droid._kernel.seam_nearest`` makes the same IEEE operations in the same order in one loop;
only the order in which numpy's ``einsum`` adds a row's three products depends on the SIMD path
numpy dispatched to on this CPU, so :func:`nearest_segment` tries each order the kernel knows
against the numpy reference, bit for bit, on seeded patches (general rows, short segments, the
tool on a point, ties, NaN), and hands out the one that matches -- or None, and the reference
stays.  ``DROID_KERNEL=python`` (droid.kernel) keeps the reference too.

The tracker is a task (docs/design.md §7: it imports no kernel); a trial puts the checked function
on its tracker (:func:`use_on`).  The trial's log is the same bytes either way.
"""
from __future__ import annotations

import numpy as np

#: seeded patches the check compares the kernel with the reference on
CHECKS = 16
#: and patches of one to three segments (where the order of einsum's sum shows in the foot)
SHORT_CHECKS = 200
_chosen: list = []  # [function or None], once per process


def _reference():
    from droid.tasks.seam.core import nearest_segment

    return nearest_segment


def _patches():
    """Seeded (tool, a, ab, den, ok) as SeamPatch.segments gives them: a path of points (spacings
    from 1e-10 to 10 mm), the tool near it, off it, on a point; some segments too short."""
    rng = np.random.default_rng(44)
    for i in range(CHECKS):
        n = int(rng.integers(2, 2500)) if i % 4 else int(rng.integers(2, 6))
        steps = rng.standard_normal((n, 3)) * 10.0 ** rng.uniform(-10, 1, (n, 1))
        if i % 5 == 0:
            steps[rng.integers(0, n, max(1, n // 7))] = 0.0  # repeated points: short segments
        P = np.cumsum(steps, axis=0) + rng.uniform(-2000, 2000, 3)
        ab = np.ascontiguousarray(P[:-1] - P[1:])
        sq = np.einsum("ij,ij->i", ab, ab)
        ok = sq > 1e-18
        den = np.where(ok, sq, 1.0)
        tool = P[int(rng.integers(0, n))].copy() if i % 3 == 0 else P[int(rng.integers(0, n))] + rng.standard_normal(3)
        if i == 7:
            tool = P[1] + (P[0] - P[1]) * 0.5  # on a segment: ties between neighbours
        a = P[1:]
        if i == 11:
            a = a.copy()
            a[n // 2 - 1] = np.nan  # a NaN row: argmin's first NaN
        yield tool, a, ab, den, ok
    for i in range(SHORT_CHECKS):  # one to three segments, the tool's foot inside one: u's last bit shows
        n = int(rng.integers(2, 5))
        P = rng.standard_normal((n, 3)) * 10.0 ** rng.uniform(-3, 3, 3) + rng.uniform(-2000, 2000, 3)
        ab = np.ascontiguousarray(P[:-1] - P[1:])
        sq = np.einsum("ij,ij->i", ab, ab)
        ok = sq > 1e-18
        yield (P[1] + ab[0] * rng.uniform(0.05, 0.95) + rng.standard_normal(3) * 10.0 ** rng.uniform(-4, 1),
               P[1:], ab, np.where(ok, sq, 1.0), ok)


def _matches(k, order: int, ref) -> bool:
    foot = np.empty(3)
    for tool, a, ab, den, ok in _patches():
        j, want = ref(tool, a, ab, den, ok)
        got = k.seam_nearest(np.ascontiguousarray(tool), a, ab, den, ok, order, foot)
        if got != j or foot.tobytes() != np.asarray(want).tobytes():
            return False
    return True


def nearest_segment():
    """The compiled nearest-segment search, checked bit for bit against the reference, as a
    function of the reference's arguments; None where it is not built, not chosen
    (``DROID_KERNEL=python``) or answers differently."""
    if _chosen:
        return _chosen[0]
    from droid import kernel

    k, fn = kernel.compiled(), None
    if k is not None and hasattr(k, "seam_nearest"):
        ref = _reference()
        for order in (0, 1):
            if _matches(k, order, ref):
                fn = _bind(k.seam_nearest, order)
                break
    _chosen.append(fn)
    return fn


def _bind(seam_nearest, order: int):
    def nearest(tool, a, ab, den, ok):
        foot = np.empty(3)
        return seam_nearest(np.ascontiguousarray(tool), a, ab, den, ok, order, foot), foot

    return nearest


def use_on(tracker) -> bool:
    """Put the checked compiled search on ``tracker`` (a SeamTracker); False: the reference stays."""
    fn = nearest_segment()
    if fn is not None:
        tracker.nearest = fn
    return fn is not None
