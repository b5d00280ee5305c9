"""The seam tracker's nearest-segment search and pose interpolation compiled, for lockstep trials (issue 44).

The thesis-mode tracker (droid.tasks.seam.core.SeamTracker.interpolate_thesis) projects the tool
point onto every segment of its seam patch each 30 Hz cycle: at 1.5 mm/s the patch from the
camera to the tool holds ~2000 frames, and the numpy expressions of
:func:`droid.tasks.seam.patch.nearest_segment` were the largest single cost of a slow trial.
``droid._kernel.seam_nearest`` makes the same IEEE operations in the same order in one loop;
only the order in which numpy's ``einsum`` adds a row's three products depends on the SIMD path
numpy dispatched to on this CPU, so :func:`nearest_segment` tries each order the kernel knows
against the numpy reference, bit for bit, on seeded patches (general rows, short segments, the
tool on a point, ties, NaN), and hands out the one that matches -- or None, and the reference
stays.  ``DROID_KERNEL=python`` (droid.kernel) keeps the reference too.

The tracking cycle's pose histories interpolate a pose between two Status poses for every
reading placed (droid.tasks.seam.cycle.interpolate_pose: three 3x3 products, the rotation's log
and exp; several times a cycle).  ``droid._kernel.pose_interp`` makes its elementwise operations
in the reference's order; what numpy leaves to its BLAS and its reduce loop -- how OpenBLAS's
dgemm sums an entry's three products (with or without FMA, in which order), how its ddot sums
``v . v``, how the trace is reduced -- is found part by part with ``pose_probe`` against numpy on
seeded inputs (:func:`pose_interpolation`), then the whole interpolation is checked against the
reference on seeded pose pairs; where no order matches, the reference stays.

The tracker is a task (docs/design.md §7: it imports no kernel); a trial puts the checked functions
on its tracker and cycle (:func:`use_on`, :func:`use_on_cycle`).  The trial's log is the same bytes
either way.
"""
from __future__ import annotations

import numpy as np

#: seeded patches the check compares the kernel with the reference on
CHECKS = 16
#: and patches of one to three segments (where the order of einsum's sum shows in the foot)
SHORT_CHECKS = 200
_chosen: list = []  # [function or None], once per process


def _reference():
    from droid.tasks.seam.patch import nearest_segment

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


# -- the pose interpolation (droid.tasks.seam.cycle.interpolate_pose) ------------------------------

#: seeded inputs each part of the interpolation is checked on, and seeded pose pairs for the whole
PART_CHECKS = 120
POSE_CHECKS = 120
#: the forms droid._kernel.pose_sum3 knows (0-5: the order and the FMAs; + 8: into a zeroed output)
FORMS = tuple(f | z for f in range(6) for z in (0, 8))
_pose_chosen: list = []  # [function or None], once per process


def _values(rng, shape) -> np.ndarray:
    """Seeded values over twelve decades, a tenth of them +-0.0 (so a zero's sign shows)."""
    v = rng.standard_normal(shape) * 10.0 ** rng.uniform(-6, 6, shape)
    v[rng.random(shape) < 0.1] = 0.0
    v[rng.random(shape) < 0.05] = -0.0
    return v


def _rotation(rng, angle_rad: float) -> np.ndarray:
    from droid.tasks.seam.cycle import _rot_exp

    axis = rng.standard_normal(3)
    return _rot_exp(axis / np.linalg.norm(axis) * angle_rad)


def _part_inputs(rng):
    """(general 4x4, general 4x4) pairs, and rotations as the tracker's poses hold them."""
    for i in range(PART_CHECKS):
        if i % 3 == 0:
            a, b = np.eye(4), np.eye(4)
            a[:3, :3] = _rotation(rng, rng.uniform(0, np.pi))
            b[:3, :3] = a[:3, :3] @ _rotation(rng, 10.0 ** rng.uniform(-9, 0.5))
        else:
            a, b = _values(rng, (4, 4)), _values(rng, (4, 4))
        yield a, b


def _part_form(k, kind: int, forms, want, args) -> list:
    """The forms of ``forms`` that give ``want(*arg)``'s bytes for every ``arg`` of ``args``."""
    out = np.empty(9 if kind < 3 else 1)
    keep = list(forms)
    for arg in args:
        ref = np.asarray(want(*arg), float).tobytes()
        a, b = arg if len(arg) == 2 else (arg[0], arg[0])
        keep = [f for f in keep if (k.pose_probe(kind, a, b, f, out), out.tobytes() == ref)[1]]
        if not keep:
            break
    return keep


def _pose_order(k) -> int | None:
    """The packed ``order`` of droid._kernel.pose_interp that does what numpy does here, or None."""
    rng = np.random.default_rng(4450)
    pairs = list(_part_inputs(rng))
    tn = _part_form(k, 0, FORMS, lambda a, b: a[:3, :3].T @ b[:3, :3], pairs)
    nn = _part_form(k, 1, FORMS, lambda a, b: a[:3, :3] @ np.ascontiguousarray(b[:3, :3]),
                    [(a, np.ascontiguousarray(b[:3, :3])) for a, b in pairs])
    nn = _part_form(k, 2, nn, lambda a, b: a @ b,
                    [(np.ascontiguousarray(a[:3, :3]), np.ascontiguousarray(b[:3, :3])) for a, b in pairs])
    dot = _part_form(k, 3, FORMS, lambda a: [float(a.dot(a))], [(np.ascontiguousarray(a[0, :3]),) for a, _ in pairs])
    tr = _part_form(k, 4, (0, 1), lambda a: [float(a.trace())],
                    [(np.ascontiguousarray(a[:3, :3] if i % 2 else a[:3, :3].T @ b[:3, :3]),)
                     for i, (a, b) in enumerate(pairs)])
    if not (tn and nn and dot and tr):
        return None
    return tn[0] | nn[0] << 4 | dot[0] << 8 | tr[0] << 12


def _pose_pairs():
    """Seeded (T0, T1, u) as a pose history holds them: poses [mm] a few degrees or a hair apart,
    the same pose twice, rotations near pi apart, u from 0 to 1."""
    rng = np.random.default_rng(4451)
    for i in range(POSE_CHECKS):
        T0 = np.eye(4)
        T0[:3, :3] = _rotation(rng, rng.uniform(0, np.pi))
        T0[:3, 3] = rng.uniform(-2000, 2000, 3)
        T1 = T0.copy()
        if i % 10:
            angle = np.pi - 10.0 ** rng.uniform(-8, -1) if i % 10 == 1 else 10.0 ** rng.uniform(-13, 0)
            T1[:3, :3] = T0[:3, :3] @ _rotation(rng, angle)
            T1[:3, 3] += rng.standard_normal(3) * 10.0 ** rng.uniform(-6, 1)
        u = (0.0, 1.0, 0.5)[i % 3] if i % 7 == 0 else float(rng.random())
        yield T0, T1, u


def pose_interpolation():
    """The compiled pose interpolation, checked bit for bit against the reference
    (droid.tasks.seam.cycle.interpolate_pose), as a function of the reference's arguments; None
    where it is not built, not chosen (``DROID_KERNEL=python``) or answers differently."""
    if _pose_chosen:
        return _pose_chosen[0]
    from droid import kernel
    from droid.tasks.seam.cycle import interpolate_pose

    k, fn = kernel.compiled(), None
    if k is not None and hasattr(k, "pose_interp"):
        order = _pose_order(k)
        if order is not None:
            fn = _bind_pose(k.pose_interp, order)
            if any(fn(T0, T1, u).tobytes() != interpolate_pose(T0, T1, u).tobytes() for T0, T1, u in _pose_pairs()):
                fn = None
    _pose_chosen.append(fn)
    return fn


def _bind_pose(pose_interp, order: int):
    def interpolate(T0, T1, u):
        out = np.empty((4, 4))
        pose_interp(T0, T1, u, order, out)
        return out

    interpolate.order = order
    return interpolate


def use_on_cycle(cyc) -> bool:
    """Put the checked compiled interpolation on the pose histories of ``cyc`` (a TrackingCycle);
    False: the reference stays."""
    fn = pose_interpolation()
    if fn is not None:
        for history in (cyc.tool_poses, cyc.hold_poses):
            history.interpolate = fn
    return fn is not None
