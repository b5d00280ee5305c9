"""Which implementation runs the guard's distance pass: compiled (droid._guard) or the Python reference.

The pass -- every arm's forward kinematics and the distance of every checked pair of bodies
(:meth:`droid.guard.cell.GuardScene.distances`) -- exists twice: the numpy reference
(:meth:`~droid.guard.cell.GuardScene.distances_reference`, with :mod:`droid.guard.distance`),
which stays the specification, and ``droid/guard/_guard.c``, a CPython extension built by pip at
install beside droid._kernel (setup.py).  ``DROID_GUARD_KERNEL`` chooses, read once at import:

* ``auto`` (the default) -- the compiled pass when it is built and agrees with the reference on
  :data:`CHECKS` seeded configurations of the scene (within :data:`AGREE_MM`), else the
  reference (:data:`UNAVAILABLE` says why, and :func:`why_not` for a scene);
* ``c`` -- the compiled pass, or :class:`GuardKernelUnavailable` (an explicit request never
  falls back);
* ``python`` -- the reference.

The two agree to :data:`AGREE_MM` (1e-9 mm), not bit for bit: numpy's einsum and batched matmul
may add a 3-term dot product in another order than the C loop.  Both give every pair's closest
points too (``closest``, :meth:`~droid.guard.cell.GuardScene.closest_points`: the guard's closing
speed along the pair's direction, droid.guard.core).  tests/guard/test_guard_kernel.py
compares them on random configurations of every shipped cell.
"""
from __future__ import annotations

import os

import numpy as np

KERNELS = ("auto", "c", "python")
ENV = "DROID_GUARD_KERNEL"
CHECKS = 64  # seeded configurations the compiled pass is compared on before a scene uses it
AGREE_MM = 1e-9
#: ... and its closest points (a near tie between two candidates may pick either: none was seen in
#: 2,000 random configurations of every shipped cell, tests/guard/test_guard_kernel.py)
AGREE_POINT_MM = 1e-6

CHOICE = os.environ.get(ENV, "auto").strip().lower() or "auto"
if CHOICE not in KERNELS:
    raise ValueError(f"{ENV}={CHOICE!r}: expected one of {', '.join(KERNELS)}")


class GuardKernelUnavailable(ImportError):
    """``DROID_GUARD_KERNEL=c`` and the compiled pass cannot be used (the message says why)."""


try:
    import droid._guard as _guard  # noqa: F401
    UNAVAILABLE = ""
except ImportError as exc:  # not built (a checkout without pip install)
    _guard = None
    UNAVAILABLE = f"droid._guard is not built ({exc}); pip install -e . builds it"

if CHOICE == "c" and _guard is None:
    raise GuardKernelUnavailable(f"{ENV}=c: {UNAVAILABLE}")


def arm_data(chain, tool_T) -> np.ndarray:
    """One arm's constants in _guard.Scene's order (the C file's header)."""
    T = np.eye(4) if tool_T is None else np.asarray(tool_T, float)
    return np.concatenate([chain.base.ravel(), chain._K.ravel(), chain._KK.ravel(), chain.offsets.ravel(),
                           chain.flange.ravel(), chain.tip_R.ravel(), T.ravel(), [0.0 if tool_T is None else 1.0]])


def build(scene):
    """A ``_guard.Scene`` of a :class:`~droid.guard.cell.GuardScene` (raises if it cannot be built)."""
    from droid.guard.bodies import FIXTURE

    names = list(scene.arms)
    arms = np.concatenate([arm_data(scene.arms[n], scene._tool_T[n]) for n in names])
    caps_i = np.array([[names.index(c.owner), c.ends[0], c.ends[1]] for c in scene.caps], np.int32).reshape(-1)
    caps_r = np.ascontiguousarray(scene.radius, float).reshape(-1)
    boxes_i = np.array([-1 if b.owner == FIXTURE else names.index(b.owner) for b in scene.boxes], np.int32)
    boxes_d = np.array([np.concatenate([np.asarray(b.T, float).ravel(), b.half_mm]) for b in scene.boxes],
                       float).reshape(-1)
    pairs = [len(scene._cc[0]), len(scene._cb[0]), len(scene._bb[0])]
    for i, j in (scene._cc, scene._cb, scene._bb):
        pairs += np.column_stack([i, j]).astype(int).ravel().tolist()
    return _guard.Scene(len(names), arms, caps_i, caps_r, boxes_i, boxes_d, np.array(pairs, np.int32))


def random_configs(scene, n: int, seed: int = 0) -> dict:
    """``n`` seeded joint vectors [deg] of every arm of ``scene`` (uniform in +-180, joints any)."""
    rng = np.random.default_rng(seed)
    return {name: rng.uniform(-180.0, 180.0, (n, 6)) for name in scene.arms}


def why_not(scene, compiled) -> str:
    """'' when the compiled pass agrees with the reference on :data:`CHECKS` seeded configurations:
    its distances (both calls) within :data:`AGREE_MM`, its closest points within :data:`AGREE_POINT_MM`."""
    if not (hasattr(compiled, "closest") and hasattr(compiled, "poses")):
        return "the compiled pass is older than droid/guard/_guard.c (no closest points): rebuild it (pip install -e .)"
    q = random_configs(scene, CHECKS, seed=41)
    want, want_a, want_b = scene.closest_points_reference(q)
    qq = np.ascontiguousarray(np.stack([q[n] for n in scene.arms], axis=1))
    got, got_a, got_b = np.empty(want.shape), np.empty(want_a.shape), np.empty(want_b.shape)
    compiled.distances(qq, got)
    worst = float(np.max(np.abs(got - want))) if want.size else 0.0
    compiled.closest(qq, got, got_a, got_b)
    worst = max(worst, float(np.max(np.abs(got - want))) if want.size else 0.0)
    if worst > AGREE_MM:
        return f"the compiled pass differs from the reference by {worst:.3g} mm"
    off = float(np.max(np.abs(np.concatenate([got_a - want_a, got_b - want_b])))) if want.size else 0.0
    if off > AGREE_POINT_MM:
        return f"the compiled pass's closest points differ from the reference's by {off:.3g} mm"
    want_poses = scene._poses(q)
    got_poses = [np.empty(w.shape) for w in want_poses]
    compiled.poses(qq, *got_poses)
    off = max((float(np.max(np.abs(g - w))) if w.size else 0.0) for g, w in zip(got_poses, want_poses))
    return "" if off <= AGREE_MM else f"the compiled pass's poses differ from the reference's by {off:.3g} mm"


def compiled_for(scene):
    """The compiled pass for ``scene`` as :data:`CHOICE` says, or None (the reference)."""
    if CHOICE == "python" or _guard is None or not scene.pairs:
        return None
    compiled = build(scene)
    why = why_not(scene, compiled)
    if why:
        if CHOICE == "c":
            raise GuardKernelUnavailable(f"{ENV}=c: {why}")
        return None
    return compiled
