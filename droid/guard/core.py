"""The guard's cycle, pure: joint vectors in, a verdict out (issue 41; docs/guard.md §5).

Each heartbeat tick :meth:`GuardCore.step` gets every arm's measured joints [deg] (its Status
``encoder_pos``), the way-point its planner sends next (its Status ``encoder_cmd``; the measured
joints for an arm no planner drives), whether it is homed and the tick of its Status, and looks
``horizon_ticks`` ahead: the arm's motion extrapolated from the commanded way-point at the
measured joint velocity.  One batched pass (:meth:`droid.guard.cell.GuardScene.closest_points`)
gives every checked pair's distance and closest points now, at the next way-point and at the
horizon.

**Closing speed, per pair** (ISO 10218-2:2025, which absorbed ISO/TS 15066: the speed of each
side *toward* the other).  For each checked pair of bodies the unit vector n from the pair's
closest point on body a to its closest point on body b (the separation direction) and the
velocities of those two material points -- exact for a rigid link: a point's displacement is
affine in its position on the body, so a capsule's point moves as its ends interpolated, a box's
as its frame -- since the arm's last Status sample (measured), toward the next way-point and over
the horizon (planned).  Each side's contribution is its *signed* speed toward the other along n [mm/s]
(a retreat is negative), the largest of its three estimates: a side counts as retreating only when
every estimate says it moves away (on a new course, no speed measured, its measured estimate is 0:
it does not count as retreating).  The pair's closing speed is the two added, signed -- a side
moving away pays for the other's approach, as ISO's speed *toward* states it: during the reaction
time T_r and the braking ramp T_s (one T_s for both arms, :class:`SsmParams`) a retreating arm
keeps adding to the separation as an approaching one takes from it, so S_p's v (T_r + T_s/2) holds
for the signed sum -- and never less than the fall of the pair's own distance (measured since the
last tick, and planned); a pair that opens is 0 (S_p its floor C + Z).  (Until 2026-12 a retreat
counted as 0: an arm turning toward one that retreated faster read as closing at its own speed and
stopped both, tests/guard/test_retreat.py.)  Where the direction is undefined -- the pair touches
or overlaps (distance <= 0: a box pair or a capsule's axis in a box has no closest points apart)
or its closest points coincide -- the conservative fallback is ISO's most conservative reading for
that pair: each body's fastest feature point (a capsule's ends, a box's
corners) as if both came straight at each other.

**The verdict**: S_p(v) per pair (:class:`~droid.guard.ssm.SsmParams`); the protective stop trips
when any judged pair's distance now is at or below its S_p, or the way-points ahead come within
C + Z; the override is the least of the pairs' (a far pair closing fast can matter less than a
near pair closing slowly).  The pair that decides is the one with the least margin d - S_p(v):
its closing speed and S_p are the verdict's, beside the least distance (at rest it is the closest
pair).  The stop latches until :meth:`release`, or until every arm has stood :data:`RELEASE_S`
with every pair above its S_p (a stop at rest below S_p stays latched until an arm is jogged away).

**Speeds that are not motion**: a measured joint step larger than :data:`JUMP_MARGIN` times the
robot file's joint speed limit (``vmax_deg_s``) allows over the ticks since the arm's last Status
sample is a re-zero (the GMF1's encoder cards zeroed at homing), not a speed: a new course for
that arm (no speed measured across it: for its first tick only its planned motion counts), said
once (:attr:`GuardVerdict.notes`).  A speed is measured over the ticks between two refreshes of
the arm's Status (its ``tick``), not over the guard's tick.  **An arm that is
not homed** (Status ``homed`` 0) has no known position (its counts are relative to where it was
powered up): its pairs are not judged -- no stop, no slowing from them -- as long as the arms'
home poses are clear of each other (:attr:`GuardCore.homes_clear`, what droid-cell up's check
proves before anything starts: homing leaves the arm there), and the protective stop is held on
while one is not homed otherwise.  It is judged again, on a new course, from the tick its Status
says homed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from droid.guard.bodies import FIXTURE
from droid.guard.cell import GuardScene, home_overlaps
from droid.guard.ssm import CLEAR, SLOWING, STOPPED, SsmParams


@dataclass
class GuardVerdict:
    """One tick's verdict: the least distance now [mm] and its pair, the least distance over the
    way-points ahead, the closing speed [mm/s] and S_p [mm] of the pair that decides (the least
    margin d - S_p; at rest the closest pair) with its distance and bodies, the override per arm,
    state (clear / slowing / stopped), ``stop`` (the protective stop is on); what the guard says
    this tick (``notes``: a re-zero, an arm not homed) and the arms whose pairs are not judged."""

    distance_mm: float  # the least distance of any judged pair now
    pair: tuple[str, str]  # its bodies: ("arm1.link_4", "gmf1.link_3")
    ahead_mm: float  # least distance over the way-points ahead
    closing_mm_s: float  # the deciding pair's
    separation_mm: float  # its S_p
    override: dict[str, float] = field(default_factory=dict)
    state: str = CLEAR
    stop: bool = False  # the protective stop is (or stays) on
    deciding_mm: float = math.inf  # the deciding pair's distance now
    deciding_pair: tuple[str, str] = ("", "")
    notes: tuple[str, ...] = ()
    unjudged: tuple[str, ...] = ()
    #: the closest points [mm, global frame] of ``pair`` now: on body a (``pair[0]``) and on body b
    #: (on a capsule's axis, on or in a box: the distance is theirs less the radii); None when
    #: nothing is judged
    points_mm: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None


@dataclass
class PairFigures:
    """Every checked pair's figures at the last step (in :attr:`GuardScene.pairs` order): distance
    now [mm], closing speed [mm/s], S_p [mm], and whether it was judged (both arms homed)."""

    distance_mm: np.ndarray
    closing_mm_s: np.ndarray
    separation_mm: np.ndarray
    judged: np.ndarray


#: the protective stop's latch ends after every arm stood this long clear of S_p [s] (GuardCore)
RELEASE_S = 1.0
#: "at rest": every pair's closing speed at most this [mm/s] (an encoder count's dither is far less)
REST_MM_S = 5.0
#: a measured joint step over this many times the robot file's joint speed limit (vmax_deg_s) over
#: the ticks since the last sample is a re-zero, not motion: 2, because a 120 Hz encoder read on a
#: 60 Hz tick can show up to 1.5 ticks of travel in one, and an arm's servo may overshoot its limit
JUMP_MARGIN = 2.0
#: ... plus this [deg]: an encoder count or two
JUMP_SLACK_DEG = 0.05
#: closest points nearer than this [mm] give no direction (the fallback)
DIR_MIN_MM = 1e-3


@dataclass
class _Course:
    """One arm's samples: the last measured joints and the tick of its Status, the joints at the
    sample before (None: a new course, no speed measured) and the time between the two, the
    measured joint velocity [deg/s] (the horizon's), whether it was homed."""

    q: np.ndarray | None = None
    tick: int = 0
    stamp_ns: int = 0
    q_prev: np.ndarray | None = None
    dt_s: float = 0.0
    vel: np.ndarray = field(default_factory=lambda: np.zeros(6))
    homed: bool | None = None


class GuardCore:
    """The guard's state between ticks: every arm's course, the pairs' last distances, the latch."""

    def __init__(self, scene: GuardScene, params: SsmParams, period_s: float, horizon_ticks: int = 3,
                 release_s: float | None = RELEASE_S) -> None:
        self.scene, self.params, self.period_s = scene, params, float(period_s)
        self.horizon = int(horizon_ticks)
        # the latch ends by itself once every arm has stood this long with the separation above
        # S_p (None: only release() ends it); a stop below S_p at rest stays until an arm is jogged away
        self.release_ticks = None if release_s is None else max(1, int(round(release_s / self.period_s)))
        self.calm = 0  # ticks in a row at rest and clear of S_p
        self.latched = False
        self.trips = 0
        self.jumps = 0  # re-zeros seen (measured steps over the joint speed limit)
        self.pair_keys = [(a.key, b.key) for a, b in scene.pairs]
        #: the arms' home poses are clear of each other (droid-cell up's check): an arm not homed
        #: is then not judged; otherwise the stop is held on while one is not homed
        self.homes_clear = not scene.pairs or home_overlaps(
            scene, {n: c.home_deg for n, c in scene.arms.items()}) is None
        self._index_pairs()
        self.pairs_now: PairFigures | None = None
        self.reset()

    def _index_pairs(self) -> None:
        """Both sides of every pair, side a's then side b's (2P entries): its capsule (an index into
        scene.caps, -1 for none), its box (into scene.boxes), its arm (-1: a fixture)."""
        sc = self.scene
        cap_ix = {id(b): i for i, b in enumerate(sc.caps)}
        box_ix = {id(b): i for i, b in enumerate(sc.boxes)}
        names = list(sc.arms)
        bodies = [p[0] for p in sc.pairs] + [p[1] for p in sc.pairs]
        self._cap = np.array([cap_ix.get(id(b), -1) for b in bodies], int)
        self._box = np.array([box_ix.get(id(b), -1) for b in bodies], int)
        self._arm = np.array([-1 if b.owner == FIXTURE else names.index(b.owner) for b in bodies], int)
        self._on_cap, self._on_box = np.flatnonzero(self._cap >= 0), np.flatnonzero(self._box >= 0)
        self._names = names

    def reset(self) -> None:
        """Forget the last tick (a new course for every arm: no speed measured across it)."""
        self._courses = {n: _Course() for n in self.scene.arms}
        self.last_d: np.ndarray | None = None
        self._said_unhomed: set[str] = set()
        self._still = None  # the last pass: (its key, d, pa, pb, closing speeds before the fall)
        self.still_passes = 0  # passes taken again at rest (the figures of the tick before)

    def release(self) -> None:
        """End a latched protective stop (a task or an operator; the next step trips again if still near)."""
        self.latched = False

    # -- one tick ------------------------------------------------------------------------------
    def step(self, q_meas: dict[str, np.ndarray], q_cmd: dict[str, np.ndarray] | None = None,
             homed: dict[str, bool] | None = None, ticks: dict[str, int] | None = None,
             stamps_ns: dict[str, int] | None = None) -> GuardVerdict:
        """One tick: joints [deg] measured and commanded (None: the measured ones) of every arm,
        whether each is homed (None: all are) and the tick of each arm's Status sample (None, or 0:
        every step is a fresh sample one tick after the last; the same tick again: no new sample).
        ``stamps_ns``: each sample's CLOCK_MONOTONIC [ns] (its Status ``updated_ns``; None or 0:
        none).  A new sample covers the ticks its Status advanced, or as many periods as its stamp
        says passed when more (:meth:`_ticks_covered`)."""
        q_cmd = q_meas if q_cmd is None else q_cmd
        sc, dt = self.scene, self.period_s
        notes: list[str] = []
        rows, new, elapsed = {}, set(), {}
        for name in sc.arms:
            c = self._courses[name]
            qm = np.asarray(q_meas[name], float)
            qc = np.asarray(q_cmd[name], float)
            is_homed = True if homed is None else bool(homed[name])
            tick = 0 if ticks is None else int(ticks.get(name) or 0)
            stamp = 0 if stamps_ns is None else int(stamps_ns.get(name) or 0)
            k = self._ticks_covered(c, tick, stamp)
            c.tick = tick or c.tick
            c.stamp_ns = stamp or c.stamp_ns
            elapsed[name] = 0
            if c.q is None:
                new.add(name)
            elif c.homed is not None and is_homed != c.homed:
                new.add(name)  # homed or un-homed: its counts mean something else now
                if is_homed:
                    notes.append(f"{name} homed: its pairs are judged again (a new course)")
            elif k > 0:  # a new sample (k == 0: the Status seen last tick, its speeds as they were)
                step = np.abs(qm - c.q)
                vmax = sc.arms[name].vmax_deg_s
                limit = JUMP_MARGIN * vmax * k * dt + JUMP_SLACK_DEG
                if np.any(step > limit):
                    new.add(name)
                    if is_homed:
                        self.jumps += 1
                        j = int(np.argmax(step / limit))
                        notes.append(f"{name} joint {j + 1} stepped {step[j]:.1f} deg in {k} tick{'s' if k > 1 else ''} "
                                     f"(over its limit of {vmax[j]:g} deg/s): a re-zero, not motion; a new course "
                                     "(no speed measured across it)")
                else:
                    c.vel, c.q_prev, c.dt_s, c.q = (qm - c.q) / (k * dt), c.q, k * dt, qm.copy()
                    elapsed[name] = k
            if name in new:
                c.q, c.q_prev, c.vel = qm.copy(), None, np.zeros(6)
            if not is_homed and name not in self._said_unhomed:
                self._said_unhomed.add(name)
                notes.append(f"{name} not homed: its position is unknown, its pairs are not judged"
                             + (" (the home poses are clear of each other)" if self.homes_clear
                                else "; the home poses are not clear of each other: the protective stop is held on"))
            elif is_homed:
                self._said_unhomed.discard(name)
            c.homed = is_homed
            # now, the next way-point, the horizon; and the sample before (now where none)
            rows[name] = np.vstack([qm, qc, qc + c.vel * self.horizon * dt, qm if c.q_prev is None else c.q_prev])
        # the pass and the closing speeds' geometry are functions of the rows and, for an arm
        # whose sample before differs from its joints now, of the time between the two: the same
        # as last tick's (the arms at rest, however their Status ticks fall) gives the same
        # figures, taken again (equal values; only the fall since the last tick and the verdict
        # are computed again)
        ok = tuple(self._courses[n].q_prev is not None for n in self._names)
        span = tuple(self._courses[n].dt_s or dt for n in self._names)
        key = (b"".join(r.tobytes() for r in rows.values()),
               tuple((o, s) if o and not np.array_equal(rows[n][3], rows[n][0]) else None
                     for n, o, s in zip(self._names, ok, span)))
        if self._still is not None and self._still[0] == key:
            _, d, pa, pb, v0 = self._still
            self.still_passes += 1
        else:
            d, pa, pb = sc.closest_points({n: r[:3] for n, r in rows.items()})  # (3, P), (3, P, 3) x2
            v0 = self._closing_geometry(d, pa, pb, sc.poses(rows), ok, span)
            self._still = (key, d, pa, pb, v0)
        v = self._closing_fall(v0, d, new, elapsed)
        self.last_d = d[0].copy()
        return self._verdict(d, v, notes, pa[0], pb[0])

    def _ticks_covered(self, c: _Course, tick: int, stamp_ns: int) -> int:
        """The heartbeat ticks a new sample covers since the arm's last (0: no new sample): its
        Status's ticks, or the periods its stamps are apart when more -- a host stall that held
        every program stretches the ticks themselves (the motion of three periods in a Status one
        tick newer read as three times its speed: a false protective stop, docs/guard.md §5).  Never
        fewer than the ticks: two replies a stalled remote wrote back to back are still a tick apart."""
        k = 1 if not (tick and c.tick) else max(0, tick - c.tick)
        if k > 0 and stamp_ns and c.stamp_ns:
            k = max(k, int(round((stamp_ns - c.stamp_ns) / (self.period_s * 1e9))))
        return k

    def _closing(self, d, pa, pb, poses, new: set[str], elapsed: dict[str, int]) -> np.ndarray:
        """Every pair's closing speed [mm/s] (the module docstring): ``poses`` of the rows now, the
        next way-point, the horizon, the sample before; ``new``: the arms on a new course;
        ``elapsed``: the ticks each arm's new sample covers (0: none this tick)."""
        ok = tuple(self._courses[n].q_prev is not None for n in self._names)
        span = tuple(self._courses[n].dt_s or self.period_s for n in self._names)
        return self._closing_fall(self._closing_geometry(d, pa, pb, poses, ok, span), d, new, elapsed)

    def _closing_geometry(self, d, pa, pb, poses, ok: tuple[bool, ...], span: tuple[float, ...]) -> np.ndarray:
        """The closing speeds [mm/s] from the pairs' closest points and the planned fall of their
        distance (the part of :meth:`_closing` that the rows decide); ``ok``: each arm has a
        speed measured, over ``span`` [s]."""
        dt, h = self.period_s, self.horizon
        P = len(self.pair_keys)
        ok_arm = np.array([*ok, True])  # [-1]: a fixture
        dt_arm = np.array([*span, 1.0])
        gap = pb[0] - pa[0]
        sep = np.sqrt(np.einsum("ij,ij->i", gap, gap))
        n = gap / np.where(sep > DIR_MIN_MM, sep, 1.0)[:, None]
        defined = (d[0] > 0.0) & (sep > DIR_MIN_MM)
        x = np.concatenate([pa[0], pb[0]])  # both sides' closest points (2P, 3)
        moved = self._moved(x, poses)  # (3, 2P, 3): to the next way-point, the horizon, the sample before
        ok, step_s = ok_arm[self._arm], dt_arm[self._arm]
        vel = np.stack([moved[0] / dt, (moved[1] - moved[0]) / (h * dt),
                        np.where(ok[:, None], -moved[2] / step_s[:, None], 0.0)])
        # each side's signed approach along n (side b's along -n; a retreat < 0), the largest of its
        # three estimates (a side retreats only when every estimate says so); the pair's: both added
        approach = np.einsum("kij,ij->ki", vel, np.concatenate([n, -n])).max(axis=0)
        v = approach[:P] + approach[P:]
        if not defined.all():  # no direction: both bodies' fastest points, straight at each other
            k = np.flatnonzero(~defined)
            both = np.concatenate([k, k + P])
            fast = self._fastest(both, poses, ok, step_s)
            v[k] = fast[:len(k)] + fast[len(k):]
        # never less than the fall of the pair's own distance planned ...
        return np.maximum(v, np.maximum((d[0] - d[1]) / dt, (d[1] - d[2]) / (h * dt)))

    def _closing_fall(self, v: np.ndarray, d, new: set[str], elapsed: dict[str, int]) -> np.ndarray:
        """... and measured since the last tick (across no new course) over the longest time its
        arms' new samples cover; never below 0."""
        dt, P, names = self.period_s, len(self.pair_keys), self._names
        falls = [v]
        if self.last_d is not None:
            a_arm, b_arm = self._arm[:P], self._arm[P:]
            cont = np.ones(P, bool)
            span = np.zeros(P)
            for i, name in enumerate(names):
                mine = (a_arm == i) | (b_arm == i)
                if name in new:
                    cont &= ~mine
                span = np.where(mine, np.maximum(span, elapsed[name]), span)
            falls.append(np.where(cont & (span > 0), (self.last_d - d[0]) / (np.maximum(span, 1.0) * dt), 0.0))
        return np.maximum(np.maximum(v, np.max(falls, axis=0)), 0.0)

    def _moved(self, x: np.ndarray, poses) -> np.ndarray:
        """The displacements (3, 2P, 3) [mm] from now to the next way-point, the horizon and the
        sample before of the pairs' material points ``x`` (2P, 3; on their bodies now): a capsule's
        point keeps its share of the way between its ends (a rigid link: the displacement is affine
        along it), a box's its coordinates in the box; a fixture stands.  ``poses``: p0, p1, bc, bR
        of the four rows.  Exactly 0 where the poses are the same."""
        p0, p1, bc, bR = poses
        out = np.zeros((3, *x.shape))
        c = self._on_cap
        if len(c):
            i = self._cap[c]
            e0, e1 = p0[0, i], p1[0, i]
            axis = e1 - e0
            L2 = np.einsum("ij,ij->i", axis, axis)
            long = L2 > 1e-12
            s = np.where(long, np.clip(np.einsum("ij,ij->i", x[c] - e0, axis) / np.where(long, L2, 1.0), 0.0, 1.0), 0.0)
            m0, m1 = p0[1:, i] - e0, p1[1:, i] - e1
            out[:, c] = m0 + s[None, :, None] * (m1 - m0)
        b = self._on_box
        if len(b):
            i = self._box[b]
            local = np.einsum("nji,nj->ni", bR[0, i], x[b] - bc[0, i])  # R^T (x - c)
            out[:, b] = (bc[1:, i] - bc[0, i]) + np.einsum("knij,nj->kni", bR[1:, i] - bR[0, i], local)
        return out

    def _fastest(self, sides: np.ndarray, poses, ok: np.ndarray, step_s: np.ndarray) -> np.ndarray:
        """The speed [mm/s] of the fastest feature point -- a capsule's ends, a box's corners -- of the
        bodies of the pair sides ``sides`` (indices into the 2P), the largest estimate: the fallback
        where a pair has no direction."""
        dt, h = self.period_s, self.horizon
        p0, p1, bc, bR = poses
        out = np.zeros(len(sides))
        cap, box = self._cap[sides], self._box[sides]
        for sel, feats in ((cap >= 0, None), (box >= 0, _CORNERS)):
            if not sel.any():
                continue
            if feats is None:  # (4, n, 2, 3): the capsules' two ends in the four rows
                i = cap[sel]
                f = np.stack([p0[:, i], p1[:, i]], axis=2)
            else:  # (4, n, 8, 3): the boxes' corners
                i = box[sel]
                local = feats[None] * self.scene.half[i][:, None, :]
                f = bc[:, i][:, :, None, :] + np.einsum("rnij,nkj->rnki", bR[:, i], local)
            m = f[1:] - f[0]  # to the next way-point, the horizon, the sample before
            sp = np.stack([np.linalg.norm(m[0], axis=-1) / dt, np.linalg.norm(m[1] - m[0], axis=-1) / (h * dt),
                           np.where(ok[sides][sel][:, None], np.linalg.norm(m[2], axis=-1) / step_s[sides][sel][:, None],
                                    0.0)])
            out[sel] = sp.max(axis=(0, 2))
        return out

    def _verdict(self, d, v: np.ndarray, notes: list[str], pa: np.ndarray, pb: np.ndarray) -> GuardVerdict:
        p = self.params
        names = self._names
        P = len(self.pair_keys)
        unjudged = tuple(n for n in names if self._courses[n].homed is False)
        judged = np.ones(P, bool)
        for n in unjudged:
            i = names.index(n)
            judged &= (self._arm[:P] != i) & (self._arm[P:] != i)
        held = bool(unjudged) and not self.homes_clear  # position unknown, home poses not proven clear
        now = d[0]
        sp = v * (p.reaction_s + 0.5 * p.stop_time_s) + p.clearance_mm + p.uncertainty_mm
        self.pairs_now = PairFigures(now.copy(), v, sp, judged)
        band = np.minimum(p.slow_mm, v * p.slow_s)
        o = np.where(band > 0.0, np.clip((now - sp) / np.where(band > 0.0, band, 1.0), 0.0, 1.0),
                     (now > sp).astype(float))
        if judged.any():
            idx = np.flatnonzero(judged)
            k = int(idx[np.argmin((now - sp)[idx])])  # the deciding pair: the least margin
            least = int(idx[np.argmin(now[idx])])
            ahead = float(np.min(d[1:, idx]))
            trip = bool(np.any(now[idx] <= sp[idx])) or ahead <= p.clearance_mm + p.uncertainty_mm
            over = float(np.min(o[idx]))
            moving = float(np.max(v[idx]))
            dk, pair, vk, spk = float(now[k]), self.pair_keys[k], float(v[k]), float(sp[k])
            least_mm, least_pair = float(now[least]), self.pair_keys[least]
            points = (tuple(float(c) for c in pa[least]), tuple(float(c) for c in pb[least]))
        else:  # nothing to judge (no arm homed)
            trip, over, moving, ahead = False, 1.0, 0.0, math.inf
            dk, pair, vk, spk = math.inf, ("", ""), 0.0, p.separation_mm(0.0)
            least_mm, least_pair = math.inf, ("", "")
            points = None
        trip = trip or held
        if trip and not self.latched:
            self.trips += 1
        self.latched = self.latched or trip
        self.calm = self.calm + 1 if (self.latched and not trip and moving <= REST_MM_S) else 0
        if self.release_ticks is not None and self.calm >= self.release_ticks:
            self.latched, self.calm = False, 0
        o_all = 0.0 if self.latched else over
        state = STOPPED if self.latched else (CLEAR if o_all >= 1.0 else SLOWING)
        return GuardVerdict(least_mm, least_pair, ahead, vk, spk, {n: o_all for n in names}, state, self.latched,
                            dk, pair, tuple(notes), unjudged, points)


#: the 8 corners of the unit box [-1, 1]^3
_CORNERS = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
