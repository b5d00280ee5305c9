"""The guard's cycle, pure: joint vectors in, a verdict out (issue 41; docs/guard.md).

Each heartbeat tick :meth:`GuardCore.step` gets every arm's measured joints [deg] (its Status
``encoder_pos``) and the way-point its planner sends next (its Status ``encoder_cmd``), and
looks ``horizon_ticks`` ahead: the arm's motion extrapolated from the commanded way-point at
the measured joint velocity.  One batched pass (:meth:`droid.guard.cell.GuardScene.distances`)
gives the least distance of every checked pair now, at the next way-point and at the horizon.

The closing speed v [mm/s] is taken as ISO's conservative "speed toward": the sum over the
arms of each arm's fastest body point (its joint origins and flange, measured since the last
tick and planned to the next way-point and the horizon), as if both came straight at each
other -- never less than the measured fall of the least distance.  S_p and the override follow
from :class:`~droid.guard.ssm.SsmParams`.  The protective stop trips when the distance now is at or
below S_p, or the way-points ahead come within C + Z (the stated limit and the uncertainty);
it latches until :meth:`release`, or until every arm has stood :data:`RELEASE_S` with the
separation above S_p (a stop at rest below S_p stays latched until an arm is jogged away).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from droid.guard.cell import GuardScene
from droid.guard.ssm import CLEAR, SLOWING, STOPPED, SsmParams


@dataclass
class GuardVerdict:
    """One tick's verdict: distances [mm], the closest pair now, the closing speed [mm/s],
    S_p [mm], the override per arm, state (clear / slowing / stopped), ``stop`` (trip now)."""

    distance_mm: float
    pair: tuple[str, str]  # ("arm1.link_4", "gmf1.link_3")
    ahead_mm: float  # least distance over the way-points ahead
    closing_mm_s: float
    separation_mm: float  # S_p
    override: dict[str, float] = field(default_factory=dict)
    state: str = CLEAR
    stop: bool = False  # the protective stop is (or stays) on


#: the protective stop's latch ends after every arm stood this long clear of S_p [s] (GuardCore)
RELEASE_S = 1.0
#: "at rest": the closing speed taken at most this [mm/s] (an encoder count's dither is far less)
REST_MM_S = 5.0


class GuardCore:
    """The guard's state between ticks: the last distance and joints, the latch."""

    def __init__(self, scene: GuardScene, params: SsmParams, period_s: float, horizon_ticks: int = 3,
                 release_s: float | None = RELEASE_S) -> None:
        self.scene, self.params, self.period_s = scene, params, float(period_s)
        self.horizon = int(horizon_ticks)
        # the latch ends by itself once every arm has stood this long with the separation above
        # S_p (None: only release() ends it); a stop below S_p at rest stays until an arm is jogged away
        self.release_ticks = None if release_s is None else max(1, int(round(release_s / self.period_s)))
        self.calm = 0  # ticks in a row at rest and clear of S_p
        self.last_q: dict[str, np.ndarray] | None = None
        self.last_d: float | None = None
        self.last_pts: dict[str, np.ndarray] = {}
        self.latched = False
        self.trips = 0
        self.pair_keys = [(a.key, b.key) for a, b in scene.pairs]

    def reset(self) -> None:
        """Forget the last tick (a new course: no speed measured across it)."""
        self.last_q, self.last_d, self.last_pts = None, None, {}

    def release(self) -> None:
        """End a latched protective stop (a task or an operator; the next step trips again if still near)."""
        self.latched = False

    def _arm_speed(self, name: str, rows: np.ndarray) -> float:
        """The fastest of the arm's body points (joint origins, flange) [mm/s]: since the last tick
        (measured) and toward the next way-point and the horizon (planned)."""
        pts, _ = self.scene.arms[name].points(np.radians(rows))  # (3, 7, 3)
        dt = self.period_s
        v = max(float(np.max(np.linalg.norm(pts[1] - pts[0], axis=1))) / dt,
                float(np.max(np.linalg.norm(pts[2] - pts[1], axis=1))) / (self.horizon * dt))
        last = self.last_pts.get(name)
        if last is not None:
            v = max(v, float(np.max(np.linalg.norm(pts[0] - last, axis=1))) / dt)
        self.last_pts[name] = pts[0]
        return v

    def step(self, q_meas: dict[str, np.ndarray], q_cmd: dict[str, np.ndarray] | None = None) -> GuardVerdict:
        """One tick: joints [deg] measured and commanded (None: the measured ones) of every arm."""
        q_cmd = q_meas if q_cmd is None else q_cmd
        rows, speed = {}, 0.0
        for name in self.scene.arms:
            qm = np.asarray(q_meas[name], float)
            qc = np.asarray(q_cmd[name], float)
            vel = (qm - self.last_q[name]) / self.period_s if self.last_q is not None else np.zeros(6)
            rows[name] = np.vstack([qm, qc, qc + vel * self.horizon * self.period_s])
            speed += self._arm_speed(name, rows[name])
        d = self.scene.distances(rows)  # (3, n_pairs)
        mins = d.min(axis=1)
        k = int(np.argmin(d[0]))
        now, ahead = float(mins[0]), float(min(mins[1], mins[2]))
        # the closing speed: every arm's fastest body point straight toward the other (ISO's
        # conservative "speed toward"), never less than the fall of the least distance itself
        measured = (self.last_d - now) / self.period_s if self.last_d is not None else 0.0
        v = max(0.0, measured, speed)
        p = self.params
        sp = p.separation_mm(v)
        trip = now <= sp or ahead <= p.clearance_mm + p.uncertainty_mm
        if trip and not self.latched:
            self.trips += 1
        self.latched = self.latched or trip
        self.calm = self.calm + 1 if (self.latched and not trip and v <= REST_MM_S) else 0
        if self.release_ticks is not None and self.calm >= self.release_ticks:
            self.latched, self.calm = False, 0
        o = 0.0 if self.latched else p.override(now, v)
        state = STOPPED if self.latched else (CLEAR if o >= 1.0 else SLOWING)
        self.last_q = {n: np.asarray(q_meas[n], float).copy() for n in self.scene.arms}
        self.last_d = now
        return GuardVerdict(now, self.pair_keys[k], ahead, v, sp, {n: o for n in self.scene.arms}, state, self.latched)
