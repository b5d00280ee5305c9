"""A robot model: geometry, gearing and limits as data, with fk / ik_all / ik (thesis §4.1.1, §4.1.7).

Build one with :func:`droid.kinematics.load_robot`.  All angles are the
robot's joint angles in degrees (for the bundled robots the D-H joint
variables of thesis Table 4.1), positions in mm, motor positions in encoder
counts relative to home.

* ``fk(q_deg)`` — eq. 4.1-4.2: the wrist-centre pose (4x4) in the world frame
  (``base @ 0T_wcp``);
* ``ik_all(T)`` — §4.1.1.2: the 8 solutions (8x6, NaN where none) before any
  limit check, numbered as in :mod:`droid.kinematics.opw`;
* ``ik(T, q_prev_deg)`` — the planner's pick (eq. 4.15): solutions outside the
  joint limits [deg] or the encoder limits [counts] are dropped (as
  joint_to_act() does), then the one minimising ``sum k_i |q_i - q_prev_i|``
  wins (ties: the lowest index, as pick_soln()).  Raises :class:`Unreachable`.

The single-pose paths are scalar ``math`` code (a few µs); the ``*_batch``
forms are vectorised numpy over N poses.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from . import opw, opw_batch
from .dh import DhTable, fk_dh
from .gearing import Gearing
from .transforms import inv_homo, is_rigid

_INF = float("inf")


class Unreachable(ValueError):
    """No inverse solution exists, or none is inside the joint/encoder limits.

    ``reason`` is a one-line explanation.
    """

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def _vec6(name: str, values, dtype=float) -> np.ndarray:
    try:
        a = np.asarray(values, dtype)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected 6 numbers") from None
    if a.shape != (6,):
        raise ValueError(f"{name}: expected 6 numbers, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: must be finite")
    a = a.copy()
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class Geometry:
    """A robot file's optional ``[geometry]``: how its URDF draws the links (droid.kinematics.urdf).

    ``link_radius_mm``: capsule radii of links 1-6 [mm] (None: nominal, from the reach);
    ``visual_mesh`` / ``collision_mesh``: 7 mesh file names or URIs (base_link, link_1 ..
    link_6; "" for the capsule), each in its URDF link frame, in metres (None: capsules).
    """

    link_radius_mm: tuple | None = None
    visual_mesh: tuple | None = None
    collision_mesh: tuple | None = None


@dataclass(frozen=True, eq=False)
class RobotModel:
    """A 6R arm of the OPW class: kinematics, gearing, limits and planner weights."""

    name: str
    description: str
    assumed: bool
    opw: opw.OpwParams
    gearing: Gearing
    joint_min_deg: np.ndarray
    joint_max_deg: np.ndarray
    counts_min: np.ndarray
    counts_max: np.ndarray
    home_switch_deg: np.ndarray
    home_search_dir: np.ndarray
    vmax_deg_s: np.ndarray
    weights: np.ndarray
    dh: DhTable | None = None
    base: np.ndarray = field(default_factory=lambda: np.eye(4))
    source: str = ""
    dynamics: object = None  # droid.kinematics.dynamics.Dynamics, or None (no [dynamics] table)
    servo_gains: object = None  # droid.kinematics.dynamics.ServoGains, or None (no [servo] table)
    axis_servo: object = None  # droid.kinematics.dynamics.AxisServo, or None (no [axis_servo] table)
    geometry: Geometry = field(default_factory=Geometry)  # [geometry]: the URDF's link drawing

    def __post_init__(self) -> None:
        for name in ("joint_min_deg", "joint_max_deg", "home_switch_deg", "vmax_deg_s", "weights"):
            object.__setattr__(self, name, _vec6(name, getattr(self, name)))
        for name in ("counts_min", "counts_max"):
            a = _vec6(name, getattr(self, name))
            if not np.all(a == np.round(a)):
                raise ValueError(f"{name}: encoder limits must be whole counts")
            a = a.astype(np.int64)
            a.flags.writeable = False
            object.__setattr__(self, name, a)
        sd = _vec6("home_search_dir", self.home_search_dir)
        if not np.all(np.isin(sd, (-1.0, 1.0))):
            raise ValueError("home_search_dir: entries must be +1 or -1")
        object.__setattr__(self, "home_search_dir", sd)
        if np.any(self.joint_min_deg >= self.joint_max_deg):
            raise ValueError("joint limits: joint_min_deg must be < joint_max_deg for every joint")
        if np.any(self.counts_min >= self.counts_max):
            raise ValueError("encoder limits: counts_min must be < counts_max for every motor")
        if np.any(self.home_switch_deg < self.joint_min_deg) or np.any(self.home_switch_deg > self.joint_max_deg):
            raise ValueError("home switch positions must lie inside the joint limits")
        if np.any(self.vmax_deg_s <= 0):
            raise ValueError("vmax_deg_s: velocity limits must be > 0")
        if np.any(self.weights < 0):
            raise ValueError("weights: planner weights must be >= 0")
        base = np.asarray(self.base, float)
        if not is_rigid(base, tol=1e-6):
            raise ValueError("base: must be a 4x4 rigid homogeneous transform (orthonormal rotation)")
        base = base.copy()
        base.flags.writeable = False
        object.__setattr__(self, "base", base)
        # ---- caches for the scalar fast paths
        ident = bool(np.array_equal(base, np.eye(4)))
        object.__setattr__(self, "_base_rows", None if ident else base[:3].tolist())
        object.__setattr__(self, "_base_inv_rows", None if ident else inv_homo(base)[:3].tolist())
        object.__setattr__(self, "_lo", tuple(self.joint_min_deg.tolist()))
        object.__setattr__(self, "_hi", tuple(self.joint_max_deg.tolist()))
        object.__setattr__(self, "_w", tuple(self.weights.tolist()))
        object.__setattr__(self, "_cmin", tuple(float(c) for c in self.counts_min))
        object.__setattr__(self, "_cmax", tuple(float(c) for c in self.counts_max))
        # If the image of the joint-limit box under the gearing lies inside the
        # encoder limits, the counts check cannot fail after the joint check
        # passed: skip it on the fast path (exact, with a 1e-6 count margin).
        m = self.gearing.joint_to_counts_matrix
        lo_img = np.minimum(m * self.joint_min_deg, m * self.joint_max_deg).sum(axis=1)
        hi_img = np.maximum(m * self.joint_min_deg, m * self.joint_max_deg).sum(axis=1)
        implied = bool(np.all(lo_img >= self.counts_min + 1e-6) and np.all(hi_img <= self.counts_max - 1e-6))
        object.__setattr__(self, "_counts_implied", implied)
        # ik()'s memo of the last pose solved: (pose bytes, hints it depended on or None, solutions)
        object.__setattr__(self, "_ik_memo", None)

    # ------------------------------------------------------------------ misc

    def with_base(self, T) -> "RobotModel":
        """A copy whose world frame is ``T`` @ robot base frame (T: 4x4 rigid, mm)."""
        return dataclasses.replace(self, base=np.asarray(T, float))

    def __repr__(self) -> str:
        tag = " (assumed)" if self.assumed else ""
        return f"RobotModel({self.name!r}{tag})"

    # ------------------------------------------------------------------ FK

    def fk(self, q_deg) -> np.ndarray:
        """Wrist-centre pose (4x4, mm) of joint angles [deg] (eq. 4.1-4.2), base included."""
        q = q_deg.tolist() if isinstance(q_deg, np.ndarray) else list(q_deg)
        if len(q) != 6:
            raise ValueError(f"fk: expected 6 joint angles, got {len(q)}")
        rows = opw.fk(self.opw, q)
        if self._base_rows is not None:
            rows = _affine_mul(self._base_rows, rows)
        rows.append([0.0, 0.0, 0.0, 1.0])
        return np.array(rows)

    def fk_batch(self, q_deg) -> np.ndarray:
        """Wrist-centre poses (N, 4, 4) of joint vectors (N, 6) [deg], base included."""
        q = np.asarray(q_deg, float)
        if q.ndim != 2 or q.shape[1] != 6:
            raise ValueError(f"fk_batch: expected (N, 6) joint angles, got shape {q.shape}")
        t = opw_batch.fk_batch(self.opw, q)
        if self._base_rows is not None:
            t = self.base @ t
        return t

    def fk_dh(self, q_deg) -> np.ndarray:
        """Reference FK as the product of the D-H A-matrices (slow; base included)."""
        if self.dh is None:
            raise ValueError(f"{self.name}: the robot file has no [dh] table")
        return self.base @ fk_dh(self.dh, q_deg)

    # ------------------------------------------------------------------ IK

    def _target_rows(self, T) -> list:
        if isinstance(T, np.ndarray) and T.shape == (4, 4):
            rows = T.tolist()
        else:
            a = np.asarray(T, float)
            if a.shape not in ((4, 4), (3, 4)):
                raise ValueError(f"target: expected a 4x4 transform, got shape {a.shape}")
            rows = a.tolist()
        r0, r1, r2 = rows[0], rows[1], rows[2]
        if not math.isfinite(sum(r0) + sum(r1) + sum(r2)):
            raise ValueError("target: transform must be finite")
        _check_rotation(r0, r1, r2)
        if self._base_inv_rows is not None:
            return _affine_mul(self._base_inv_rows, [r0, r1, r2])
        return rows

    def ik_all(self, T, q_hint_deg=None) -> np.ndarray:
        """All 8 inverse solutions (8x6, deg, NaN where none) of a wrist-centre pose T (4x4, mm).

        No limits are applied.  ``q_hint_deg`` (previous joint angles) gives
        joint 1 at the shoulder singularity and joint 4 at the wrist
        singularity (default 0).
        """
        rows = self._target_rows(T)
        h1, h4 = _hints(q_hint_deg)
        return np.array(opw.ik(self.opw, rows, h1, h4))

    def ik_all_batch(self, Ts, q_hint_deg=None, hint_used=None) -> np.ndarray:
        """All 8 solutions of N poses (N, 4, 4) -> (N, 8, 6) [deg], NaN where none (vectorised).

        ``q_hint_deg`` (6,) or (N, 6) as for :meth:`ik_all`; a bool array
        ``hint_used`` (N,) is set True where a singular configuration used it.
        """
        t = np.asarray(Ts, float)
        if t.ndim != 3 or t.shape[1:] != (4, 4):
            raise ValueError(f"ik_all_batch: expected (N, 4, 4) transforms, got shape {t.shape}")
        if self._base_rows is not None:
            t = inv_homo(self.base) @ t
        if q_hint_deg is not None:
            h = np.asarray(q_hint_deg, float)
            if h.shape not in ((6,), (t.shape[0], 6)):
                raise ValueError("q_hint_deg: expected (6,) or (N, 6)")
        if not np.all(np.isfinite(t)):
            raise ValueError("ik_all_batch: transforms must be finite")
        bad = ~(_rotation_error(t) <= ROTATION_TOL)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"ik_all_batch: pose {i}: rotation is not orthonormal and right-handed")
        return opw_batch.ik_batch(self.opw, t, q_hint_deg, hint_used)

    def ik_batch(self, Ts, q_prev_deg) -> tuple[np.ndarray, np.ndarray]:
        """The planner's pick for N poses (N, 4, 4): (joint angles (N, 6) [deg], index (N,)).

        Vectorised :meth:`ik` without the memo: all 8 solutions and the pick
        (eq. 4.15) per chunk of ``opw_batch.BATCH_CHUNK`` poses so the
        temporaries stay in cache.  ``q_prev_deg`` (6,) or (N, 6) is the
        previous joint vector (also the singularity hint); rows with no
        commandable solution are NaN with index -1 (no exception).
        """
        t = np.asarray(Ts, float)
        if t.ndim != 3 or t.shape[1:] != (4, 4):
            raise ValueError(f"ik_batch: expected (N, 4, 4) transforms, got shape {t.shape}")
        n = t.shape[0]
        prev = np.asarray(q_prev_deg, float)
        if prev.shape == (6,):
            prev = np.broadcast_to(prev, (n, 6))
        if prev.shape != (n, 6) or not np.all(np.isfinite(prev)):
            raise ValueError("q_prev_deg: expected (6,) or (N, 6) finite joint angles")
        q = np.full((n, 6), np.nan)
        idx = np.empty(n, np.int64)
        step = opw_batch.BATCH_CHUNK
        rows = np.arange(min(n, step))
        for i in range(0, n, step):
            j = min(n, i + step)
            sols = self.ik_all_batch(t[i:j], prev[i:j])
            k = self.pick_batch(sols, prev[i:j])
            idx[i:j] = k
            r = rows[: j - i]
            ok = k >= 0
            q[i:j][ok] = sols[r[ok], k[ok]]
        return q, idx

    def ik(self, T, q_prev_deg) -> np.ndarray:
        """The planner's pick (eq. 4.15) for pose T (4x4, mm): 6 joint angles [deg].

        Raises :class:`Unreachable` if no solution exists or none is inside
        the joint and encoder limits.

        The 8 solutions of the last pose are kept: the same pose (a 4x4
        float array, byte for byte) asked again, e.g. by the seam tracker's
        reach check and then by the planner, is picked from them (they do
        not depend on ``q_prev_deg`` unless the pose is singular, and then
        they are solved again).
        """
        key = T.tobytes() if type(T) is np.ndarray and T.dtype == np.float64 and T.shape == (4, 4) else None
        memo = self._ik_memo
        if key is None or memo is None or memo[0] != key:
            memo = None
            rows = self._target_rows(T)
        prev = q_prev_deg.tolist() if isinstance(q_prev_deg, np.ndarray) else [float(v) for v in q_prev_deg]
        if len(prev) != 6 or not math.isfinite(sum(prev)):
            raise ValueError("q_prev_deg: expected 6 finite joint angles")
        if memo is not None and (memo[1] is None or memo[1] == (prev[0], prev[3])):
            sols = memo[2]
        else:
            if memo is not None:
                rows = self._target_rows(T)
            sols, hinted = opw.ik_hinted(self.opw, rows, prev[0], prev[3])
            if key is not None:
                object.__setattr__(self, "_ik_memo", (key, (prev[0], prev[3]) if hinted else None, sols))
        i = self.pick_index(sols, prev)
        if i < 0:
            raise Unreachable(self.explain(sols))
        return np.array(sols[i])

    # ------------------------------------------------------------------ pick

    def limit_violation(self, q_deg) -> str | None:
        """Why joint angles [deg] are not commandable (joint or encoder limits), or None if they are."""
        q = [float(v) for v in q_deg]
        if any(v != v for v in q):
            return "no solution"
        lo, hi = self._lo, self._hi
        for j in range(6):
            if q[j] < lo[j]:
                return f"j{j + 1} {q[j]:.2f} < min {lo[j]:g} deg"
            if q[j] > hi[j]:
                return f"j{j + 1} {q[j]:.2f} > max {hi[j]:g} deg"
        return self._counts_violation(q)

    def _counts_violation(self, q: list) -> str | None:
        cmin, cmax = self._cmin, self._cmax
        for i, row in enumerate(self.gearing.sparse_rows):
            c = 0.0
            for j, m in row:
                c += m * q[j]
            if c < cmin[i]:
                return f"motor {i + 1} {c:.0f} < min {cmin[i]:.0f} counts"
            if c > cmax[i]:
                return f"motor {i + 1} {c:.0f} > max {cmax[i]:.0f} counts"
        return None

    def within_limits(self, q_deg) -> bool:
        """True if joint angles [deg] are inside the joint limits and their counts inside the encoder limits."""
        return self.limit_violation(q_deg) is None

    def pick_index(self, solutions, q_prev_deg) -> int:
        """Index of the planner's pick among 8 solutions (eq. 4.15), or -1 if none is valid.

        A solution is valid if it exists (no NaN) and is inside the joint
        limits [deg] and the encoder limits [counts].  Score:
        ``sum_i k_i |q_i - q_prev_i|`` [weighted deg]; ties go to the lowest index.
        """
        p0, p1, p2, p3, p4, p5 = q_prev_deg
        w0, w1, w2, w3, w4, w5 = self._w
        best, best_score = -1, _INF
        i = 0
        for a, b, c, d, e, f in solutions:
            score = (
                w0 * abs(a - p0) + w1 * abs(b - p1) + w2 * abs(c - p2)
                + w3 * abs(d - p3) + w4 * abs(e - p4) + w5 * abs(f - p5)
            )
            if score < best_score:  # strict: ties keep the lowest index; NaN rows never win
                best, best_score = i, score
            i += 1
        if best < 0:
            return -1
        # usually the best-scored solution is commandable: check it alone first
        if self._commandable(solutions[best]):
            return best
        scored = []
        for i, (a, b, c, d, e, f) in enumerate(solutions):
            score = (
                w0 * abs(a - p0) + w1 * abs(b - p1) + w2 * abs(c - p2)
                + w3 * abs(d - p3) + w4 * abs(e - p4) + w5 * abs(f - p5)
            )
            if score == score and i != best:
                scored.append((score, i))
        scored.sort()
        for _, i in scored:
            if self._commandable(solutions[i]):
                return i
        return -1

    def _commandable(self, s) -> bool:
        """Fast limit check of one solution (6 deg) for :meth:`pick_index`."""
        a, b, c, d, e, f = s
        lo, hi = self._lo, self._hi
        if (
            lo[0] <= a <= hi[0] and lo[1] <= b <= hi[1] and lo[2] <= c <= hi[2]
            and lo[3] <= d <= hi[3] and lo[4] <= e <= hi[4] and lo[5] <= f <= hi[5]
        ):
            return self._counts_implied or self._counts_violation(list(s)) is None
        return False

    def explain(self, solutions) -> str:
        """One-line reason why no solution of ``solutions`` (8x6) is commandable."""
        sols = np.asarray(solutions, float)
        if np.all(np.isnan(sols)):
            return "target out of reach (no inverse solution: outside the workspace)"
        parts = []
        for i, s in enumerate(sols):
            if np.isnan(s).any():
                continue
            why = self.limit_violation(s)
            if why is not None:
                parts.append(f"sol {i}: {why}")
        return "no solution inside the limits: " + "; ".join(parts)

    def pick_batch(self, solutions, q_prev_deg) -> np.ndarray:
        """Vectorised pick for N poses: solutions (N, 8, 6), q_prev (6,) or (N, 6) -> (N,) index, -1 if none."""
        s = np.asarray(solutions, float)
        prev = np.asarray(q_prev_deg, float)
        if prev.ndim == 1:
            prev = prev[None, :]
        prev = prev[:, None, :]
        lo, hi, w = self._lo, self._hi, self._w
        with np.errstate(invalid="ignore"):
            # joint by joint over (N, 8) planes: numpy reduces a last axis of 6 slowly
            sj = s[..., 0]
            valid = (sj >= lo[0]) & (sj <= hi[0])  # NaN (no solution) fails
            score = np.abs(sj - prev[..., 0]) * w[0]
            for j in range(1, 6):
                sj = s[..., j]
                valid &= sj >= lo[j]
                valid &= sj <= hi[j]
                d = sj - prev[..., j]
                np.abs(d, out=d)
                d *= w[j]
                score += d
            if not self._counts_implied:
                c = s @ self.gearing.joint_to_counts_matrix.T
                valid &= np.all((c >= self.counts_min) & (c <= self.counts_max), axis=2)
        score[~valid] = _INF
        idx = np.argmin(score, axis=1)  # first minimum: lowest index on ties
        idx[~valid.any(axis=1)] = -1
        return idx


#: tolerance on R^T R = I (and R's middle column = z x x) of a target.
ROTATION_TOL = 1e-6


def _check_rotation(r0: list, r1: list, r2: list) -> None:
    """Raise ValueError unless the 3x3 part of a target is a rotation (orthonormal, right-handed)."""
    x0, x1, x2 = r0[0], r1[0], r2[0]
    y0, y1, y2 = r0[1], r1[1], r2[1]
    z0, z1, z2 = r0[2], r1[2], r2[2]
    err = max(
        abs(x0 * x0 + x1 * x1 + x2 * x2 - 1.0),
        abs(z0 * z0 + z1 * z1 + z2 * z2 - 1.0),
        abs(x0 * z0 + x1 * z1 + x2 * z2),
        abs(z1 * x2 - z2 * x1 - y0),
        abs(z2 * x0 - z0 * x2 - y1),
        abs(z0 * x1 - z1 * x0 - y2),
    )
    if not err <= ROTATION_TOL:
        raise ValueError(f"target: rotation is not orthonormal and right-handed (error {err:.2g})")


def _rotation_error(t: np.ndarray) -> np.ndarray:
    """Vector form of :func:`_check_rotation`'s error for (N, 4, 4) targets."""
    x0, x1, x2 = t[:, 0, 0], t[:, 1, 0], t[:, 2, 0]
    y0, y1, y2 = t[:, 0, 1], t[:, 1, 1], t[:, 2, 1]
    z0, z1, z2 = t[:, 0, 2], t[:, 1, 2], t[:, 2, 2]
    err = np.abs(x0 * x0 + x1 * x1 + x2 * x2 - 1.0)
    np.maximum(err, np.abs(z0 * z0 + z1 * z1 + z2 * z2 - 1.0), out=err)
    np.maximum(err, np.abs(x0 * z0 + x1 * z1 + x2 * z2), out=err)
    np.maximum(err, np.abs(z1 * x2 - z2 * x1 - y0), out=err)
    np.maximum(err, np.abs(z2 * x0 - z0 * x2 - y1), out=err)
    np.maximum(err, np.abs(z0 * x1 - z1 * x0 - y2), out=err)
    return err


def _hints(q_hint_deg) -> tuple[float, float]:
    if q_hint_deg is None:
        return 0.0, 0.0
    h = [float(v) for v in q_hint_deg]
    if len(h) != 6 or not math.isfinite(h[0] + h[3]):
        raise ValueError("q_hint_deg: expected 6 finite joint angles")
    return h[0], h[3]


def _affine_mul(a: list, b: list) -> list:
    """Product of two 3x4 affine transforms given as nested lists (rows)."""
    out = []
    b0, b1, b2 = b
    for r in a:
        x, y, z, t = r
        out.append(
            [
                x * b0[0] + y * b1[0] + z * b2[0],
                x * b0[1] + y * b1[1] + z * b2[1],
                x * b0[2] + y * b1[2] + z * b2[2],
                x * b0[3] + y * b1[3] + z * b2[3] + t,
            ]
        )
    return out
