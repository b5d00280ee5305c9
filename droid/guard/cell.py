"""The cell's bodies, its allowed-collision table and one guard pass over every pair (issue 41).

:func:`guard_scene` reads a cell (its arms' robot files and bases, the mounts of its world
devices, its ``[guard]`` table) into a :class:`GuardScene`; :meth:`GuardScene.distances`
gives the distance [mm] of every checked pair for the arms' joint vectors [deg], and
:meth:`GuardScene.closest` the least of them and its pair.

Checked pairs: every pair of bodies of two different arms, and every arm body against every
fixture, less the pairs the ``[guard] allow`` table names.  Bodies of one arm are never
checked against each other (adjacent links touch by construction; the arm's own limits keep
the others apart).  The ``[guard]`` table (docs/guard.md)::

    [guard]
    allow = [["arm1.tool", "gmf1.workpiece"], ["arm1.link_1", "fixture.floor"]]
    workpiece = { arm = "gmf1", pose = [351, 26, -5, 0, 0, 0], size_mm = [724, 156, 12] }  # pose: in W
    fixtures = [{ name = "floor", pose = [0, 0, -50, 0, 0, 0], size_mm = [6000, 4000, 100] }]

A body is named ``ARM.link_N`` (N = 1..6), ``ARM.tool``, ``ARM.sensor``, ``ARM.workpiece`` or
``fixture.NAME``; a name the cell does not have is one line, exit 2 (:class:`BadInput`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from droid.cli import BadInput
from droid.guard import distance as dist
from droid.guard.bodies import FIXTURE, ArmChain, Body, _box_spec, _held_mount, arm_bodies
from droid.kinematics import load_robot
from droid.kinematics.cli import cell_mounts
from droid.kinematics.robots import RobotFileError
from droid.kinematics.transforms import pose_to_T

GUARD_KEYS = {"allow", "workpiece", "fixtures", "ssm", "stale_ticks", "run"}


@dataclass
class Closest:
    """The least distance of a pass [mm] and its pair (body keys ``arm.link_N``)."""

    distance_mm: float
    a: Body
    b: Body

    @property
    def in_collision(self) -> bool:
        return self.distance_mm <= dist.OVERLAP_MM

    def as_dict(self) -> dict:
        return {"distance_mm": round(self.distance_mm, 3), "a": self.a.key, "b": self.b.key,
                "in_collision": self.in_collision}


class GuardScene:
    """Bodies of several arms and fixtures with the index arrays of the pairs to check."""

    def __init__(self, arms: dict[str, ArmChain], bodies: list[Body], allow: set[frozenset]) -> None:
        self.arms = arms
        self.bodies = bodies
        self.caps = [b for b in bodies if b.kind == "capsule"]
        self.boxes = [b for b in bodies if b.kind == "box"]
        self._tool_T = {a: next((b.T for b in bodies if b.owner == a and b.name == "tool"), None) for a in arms}
        self.radius = np.array([b.radius_mm for b in self.caps])
        self.half = np.array([b.half_mm for b in self.boxes]).reshape(-1, 3)
        self.pairs: list[tuple[Body, Body]] = []
        self._compiled = False  # not chosen yet (droid.guard.kernel, on first use)
        idx = {"cc": ([], []), "cb": ([], []), "bb": ([], [])}
        for kind_a, list_a, kind_b, list_b, key in (("c", self.caps, "c", self.caps, "cc"),
                                                     ("c", self.caps, "b", self.boxes, "cb"),
                                                     ("b", self.boxes, "b", self.boxes, "bb")):
            for i, a in enumerate(list_a):
                for j, b in enumerate(list_b):
                    if key != "cb" and j <= i:
                        continue
                    if not _checked(a, b, allow):
                        continue
                    idx[key][0].append(i)
                    idx[key][1].append(j)
        for key, lists in (("cc", (self.caps, self.caps)), ("cb", (self.caps, self.boxes)), ("bb", (self.boxes, self.boxes))):
            i, j = (np.array(v, int) for v in idx[key])
            setattr(self, f"_{key}", (i, j))
            self.pairs += [(lists[0][a], lists[1][b]) for a, b in zip(i, j)]

    @property
    def n_pairs(self) -> int:
        return len(self.pairs)

    def _poses(self, q_deg: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Capsule ends (B, Nc, 3) x2 and box centres (B, Nb, 3) and rotations (B, Nb, 3, 3) [mm, global]."""
        B = next(iter(q_deg.values())).shape[0] if q_deg else 1
        pts, tool0 = {}, {}
        for name, chain in self.arms.items():
            q = np.radians(np.asarray(q_deg[name], float).reshape(-1, 6))
            p, t0 = chain.points(q)
            tool_pt = t0[:, :3, 3] if self._tool_T[name] is None else (t0 @ self._tool_T[name])[:, :3, 3]
            pts[name] = np.concatenate([p, tool_pt[:, None, :]], axis=1)
            tool0[name] = t0
        p0 = np.empty((B, len(self.caps), 3))
        p1 = np.empty_like(p0)
        for k, c in enumerate(self.caps):
            p0[:, k], p1[:, k] = pts[c.owner][:, c.ends[0]], pts[c.owner][:, c.ends[1]]
        bc = np.empty((B, len(self.boxes), 3))
        bR = np.empty((B, len(self.boxes), 3, 3))
        for k, bx in enumerate(self.boxes):
            T = bx.T if bx.owner == FIXTURE else tool0[bx.owner] @ bx.T
            bc[:, k], bR[:, k] = T[..., :3, 3], T[..., :3, :3]
        return p0, p1, bc, bR

    @property
    def compiled(self):
        """The compiled pass (droid._guard.Scene) this scene uses, or None (droid.guard.kernel)."""
        if self._compiled is False:
            from droid.guard.kernel import compiled_for

            self._compiled = compiled_for(self)
        return self._compiled

    def distances(self, q_deg: dict[str, np.ndarray]) -> np.ndarray:
        """Distances (B, n_pairs) [mm] of every checked pair, in :attr:`pairs` order, for joint vectors
        (B, 6) or (6,) [deg] of every arm (a box pair that overlaps reports <= 0, docs/guard.md):
        the compiled pass where droid.guard.kernel chooses it, else :meth:`distances_reference`."""
        k = self.compiled
        if k is None:
            return self.distances_reference(q_deg)
        rows = np.broadcast_arrays(*[np.asarray(q_deg[n], float).reshape(-1, 6) for n in self.arms])
        q = np.ascontiguousarray(np.stack(rows, axis=1))  # (B, n_arms, 6)
        out = np.empty((q.shape[0], len(self.pairs)))
        k.distances(q, out)
        return out

    def distances_reference(self, q_deg: dict[str, np.ndarray]) -> np.ndarray:
        """:meth:`distances` in numpy: the specification of the compiled pass (droid/guard/_guard.c)."""
        p0, p1, bc, bR = self._poses(q_deg)
        B = p0.shape[0]
        out = []
        i, j = self._cc
        if len(i):
            d = dist.segment_segment(p0[:, i], p1[:, i], p0[:, j], p1[:, j])
            out.append(d - self.radius[i] - self.radius[j])
        # every segment against a box -- the capsules' axes and both boxes' edges of a box pair,
        # each in its box's frame -- in one call (numpy's cost is per call, not per element)
        i, k = self._cb
        kb, mb = self._bb
        segs_a, segs_b, halves = [], [], []
        if len(i):
            c, R = bc[:, k].reshape(-1, 3), bR[:, k].reshape(-1, 3, 3)
            segs_a.append(dist.to_box_frame(p0[:, i].reshape(-1, 1, 3), c, R)[:, 0])
            segs_b.append(dist.to_box_frame(p1[:, i].reshape(-1, 1, 3), c, R)[:, 0])
            halves.append(np.broadcast_to(self.half[k], (B, len(k), 3)).reshape(-1, 3))
        for src, dst in ((kb, mb), (mb, kb)):
            if not len(src):
                continue
            hs = np.broadcast_to(self.half[src], (B, len(src), 3)).reshape(-1, 3)
            hd = np.broadcast_to(self.half[dst], (B, len(dst), 3)).reshape(-1, 3)
            e = dist.to_box_frame(dist.box_edges(bc[:, src].reshape(-1, 3), bR[:, src].reshape(-1, 3, 3), hs),
                                  bc[:, dst].reshape(-1, 3), bR[:, dst].reshape(-1, 3, 3))
            segs_a.append(e[:, :, 0].reshape(-1, 3))
            segs_b.append(e[:, :, 1].reshape(-1, 3))
            halves.append(np.repeat(hd, 12, axis=0))
        if segs_a:
            d = dist.segment_box(np.concatenate(segs_a), np.concatenate(segs_b), np.concatenate(halves))
            n_cb = B * len(i)
            if len(i):
                d_cb = d[:n_cb].reshape(B, -1)
                out.append(np.where(d_cb > 0.0, d_cb - self.radius[i], -self.radius[i]))
            if len(kb):
                n = B * len(kb) * 12
                ab = d[n_cb:n_cb + n].reshape(B, len(kb), 12).min(axis=2)
                ba = d[n_cb + n:n_cb + 2 * n].reshape(B, len(kb), 12).min(axis=2)
                out.append(np.minimum(ab, ba))
        return np.concatenate(out, axis=1) if out else np.full((B, 0), np.inf)

    def closest_points(self, q_deg: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`distances` and every pair's closest points [mm, global]: (d (B, P), on a (B, P, 3),
        on b (B, P, 3)) for the pair (a, b) of :attr:`pairs` -- a capsule's point on its axis (the
        distance is the points' less both radii), a box's on or in it; where a box pair overlaps or a
        capsule's axis enters a box both points are the axis's (the edge's) entry point.  The
        compiled pass where droid.guard.kernel chooses it, else :meth:`closest_points_reference`."""
        k = self.compiled
        if k is None:
            return self.closest_points_reference(q_deg)
        rows = np.broadcast_arrays(*[np.asarray(q_deg[n], float).reshape(-1, 6) for n in self.arms])
        q = np.ascontiguousarray(np.stack(rows, axis=1))  # (B, n_arms, 6)
        B, P = q.shape[0], len(self.pairs)
        out, pa, pb = np.empty((B, P)), np.empty((B, P, 3)), np.empty((B, P, 3))
        k.closest(q, out, pa, pb)
        return out, pa, pb

    def poses(self, q_deg: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The bodies' poses [mm, global]: capsule ends (B, Nc, 3) x2, box centres (B, Nb, 3) and
        rotations (B, Nb, 3, 3) -- the compiled pass's forward kinematics where droid.guard.kernel
        chooses it, else :meth:`_poses` (the reference)."""
        k = self.compiled
        if k is None:
            return self._poses(q_deg)
        rows = np.broadcast_arrays(*[np.asarray(q_deg[n], float).reshape(-1, 6) for n in self.arms])
        q = np.ascontiguousarray(np.stack(rows, axis=1))
        B, nc, nb = q.shape[0], len(self.caps), len(self.boxes)
        p0, p1, bc, bR = np.empty((B, nc, 3)), np.empty((B, nc, 3)), np.empty((B, nb, 3)), np.empty((B, nb, 3, 3))
        k.poses(q, p0, p1, bc, bR)
        return p0, p1, bc, bR

    def closest_points_reference(self, q_deg: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`closest_points` in numpy: the specification of the compiled pass's ``closest``
        (its distances are :meth:`distances_reference`'s, operation for operation)."""
        p0, p1, bc, bR = self._poses(q_deg)
        B = p0.shape[0]
        d_out, a_out, b_out = [], [], []
        i, j = self._cc
        if len(i):
            d, ca, cb = dist.segment_segment_points(p0[:, i], p1[:, i], p0[:, j], p1[:, j])
            d_out.append(d - self.radius[i] - self.radius[j])
            a_out.append(ca)
            b_out.append(cb)
        i, k = self._cb
        kb, mb = self._bb
        segs_a, segs_b, halves, frames = [], [], [], []
        if len(i):
            c, R = bc[:, k].reshape(-1, 3), bR[:, k].reshape(-1, 3, 3)
            segs_a.append(dist.to_box_frame(p0[:, i].reshape(-1, 1, 3), c, R)[:, 0])
            segs_b.append(dist.to_box_frame(p1[:, i].reshape(-1, 1, 3), c, R)[:, 0])
            halves.append(np.broadcast_to(self.half[k], (B, len(k), 3)).reshape(-1, 3))
            frames.append((c, R))
        for src, dst in ((kb, mb), (mb, kb)):
            if not len(src):
                continue
            hs = np.broadcast_to(self.half[src], (B, len(src), 3)).reshape(-1, 3)
            hd = np.broadcast_to(self.half[dst], (B, len(dst), 3)).reshape(-1, 3)
            c, R = bc[:, dst].reshape(-1, 3), bR[:, dst].reshape(-1, 3, 3)
            e = dist.to_box_frame(dist.box_edges(bc[:, src].reshape(-1, 3), bR[:, src].reshape(-1, 3, 3), hs), c, R)
            segs_a.append(e[:, :, 0].reshape(-1, 3))
            segs_b.append(e[:, :, 1].reshape(-1, 3))
            halves.append(np.repeat(hd, 12, axis=0))
            frames.append((np.repeat(c, 12, axis=0), np.repeat(R, 12, axis=0)))
        if segs_a:
            d, cs, cb = dist.segment_box_points(np.concatenate(segs_a), np.concatenate(segs_b), np.concatenate(halves))
            c = np.concatenate([f[0] for f in frames])
            R = np.concatenate([f[1] for f in frames])
            gs = c + np.einsum("nij,nj->ni", R, cs)  # back to the global frame
            gb = c + np.einsum("nij,nj->ni", R, cb)
            n_cb = B * len(i)
            if len(i):
                d_cb = d[:n_cb].reshape(B, -1)
                d_out.append(np.where(d_cb > 0.0, d_cb - self.radius[i], -self.radius[i]))
                a_out.append(gs[:n_cb].reshape(B, -1, 3))
                b_out.append(gb[:n_cb].reshape(B, -1, 3))
            if len(kb):
                n = B * len(kb) * 12
                halves_d = []
                for off in (n_cb, n_cb + n):  # a's edges in b's frame, then b's edges in a's frame
                    dd = d[off:off + n].reshape(B, len(kb), 12)
                    m = np.argmin(dd, axis=2)  # the first least edge
                    sel = lambda x: np.take_along_axis(x[off:off + n].reshape(B, len(kb), 12, 3),  # noqa: E731
                                                       m[..., None, None], axis=2)[:, :, 0]
                    halves_d.append((np.take_along_axis(dd, m[..., None], axis=2)[..., 0], sel(gs), sel(gb)))
                (ab, ab_s, ab_b), (ba, ba_s, ba_b) = halves_d
                first = (ab <= ba)[..., None]
                d_out.append(np.minimum(ab, ba))
                a_out.append(np.where(first, ab_s, ba_b))  # a's edge, or the point of box a
                b_out.append(np.where(first, ab_b, ba_s))
        if not d_out:
            return np.full((B, 0), np.inf), np.zeros((B, 0, 3)), np.zeros((B, 0, 3))
        return np.concatenate(d_out, axis=1), np.concatenate(a_out, axis=1), np.concatenate(b_out, axis=1)

    def closest(self, q_deg: dict[str, np.ndarray]) -> Closest:
        """The least distance [mm] over every checked pair for one joint vector [deg] of every arm."""
        d = self.distances({k: np.asarray(v, float).reshape(1, 6) for k, v in q_deg.items()})[0]
        if not d.size:
            raise BadInput("guard: no pair of bodies to check (one arm and no fixture?)")
        k = int(np.argmin(d))
        return Closest(float(d[k]), *self.pairs[k])


def _checked(a: Body, b: Body, allow: set[frozenset]) -> bool:
    if a.owner == b.owner:
        return False
    return frozenset((a.key, b.key)) not in allow


def _arm_chain(cell, name: str) -> tuple[ArmChain, object, dict]:
    sub = cell.subunits[name]
    try:
        model = load_robot(sub.robot)
    except RobotFileError as exc:
        raise BadInput(f"{cell.path}: [subunits.{name}] robot: {exc}") from None
    _, mounts = cell_mounts(cell.raw, name, str(cell.path))
    return ArmChain(model, pose_to_T(*[float(v) for v in sub.base])), model, mounts


def guard_table(cell) -> dict:
    """The cell's ``[guard]`` table ({} when it has none); unknown keys are one line."""
    table = cell.raw.get("guard", {})
    if not isinstance(table, dict):
        raise BadInput(f"{cell.path}: [guard]: must be a table")
    unknown = sorted(set(table) - GUARD_KEYS)
    if unknown:
        raise BadInput(f"{cell.path}: [guard] unknown key(s): {', '.join(unknown)} (known: {', '.join(sorted(GUARD_KEYS))})")
    return table


def _held(cell, table: dict) -> list[tuple[str, dict]]:
    """``[guard] workpiece``: a box (``pose``: its centre in the workpiece frame W, ``size_mm``) on the
    wrist of ``arm`` at ``mount`` (T_wcp_W; default: the world devices' ``workpiece_mount`` on that arm),
    or a list of such boxes (a workpiece of several straight parts: step_input's two legs), each a
    body ``ARM.workpiece``.  Returns [(arm, held body spec)]."""
    wp = table.get("workpiece")
    if wp is None:
        return []
    if isinstance(wp, list):
        if not wp:
            raise BadInput(f"{cell.path}: [guard] workpiece: an empty list (give a box, or no workpiece)")
        return [_held_box(cell, w, f"{cell.path}: [guard] workpiece[{n}]") for n, w in enumerate(wp)]
    return [_held_box(cell, wp, f"{cell.path}: [guard] workpiece")]


def _held_box(cell, wp, where: str) -> tuple[str, dict]:
    arm = wp.get("arm") if isinstance(wp, dict) else None
    if arm not in cell.subunits or not cell.subunits[arm].is_arm:
        raise BadInput(f"{where}: arm: {arm!r} is not an arm of the cell (arms: {', '.join(_arms(cell))})")
    T, half = _box_spec(where, {k: v for k, v in wp.items() if k != "mount"})
    mount = wp.get("mount")
    if mount is None:
        M = _held_mount(cell.raw, arm)
        if M is None:
            raise BadInput(f"{where}: mount: no world device mounts a workpiece on {arm!r}; give mount (T_wcp_W)")
    elif isinstance(mount, list) and len(mount) == 6 and all(isinstance(v, (int, float)) for v in mount):
        M = pose_to_T(*[float(v) for v in mount])
    else:
        raise BadInput(f"{where}: mount: expected [x, y, z, A, B, C] (mm, ZYZ deg)")
    return arm, {"name": "workpiece", "T": M @ T, "half_mm": half}


def _arms(cell) -> list[str]:
    return [n for n, s in cell.subunits.items() if s.is_arm and s.robot]


def guard_scene(cell) -> GuardScene:
    """The :class:`GuardScene` of a parsed cell (:class:`~droid.brain.cell.cellfile.Cell`)."""
    table = guard_table(cell)
    held = _held(cell, table)
    arms, bodies = {}, []
    for name in _arms(cell):
        chain, model, mounts = _arm_chain(cell, name)
        arms[name] = chain
        bodies += arm_bodies(name, model, mounts, None)
        bodies += [Body(name, h["name"], "box", T=h["T"], half_mm=h["half_mm"]) for a, h in held if a == name]
    fixtures = table.get("fixtures", [])
    if not isinstance(fixtures, list):
        raise BadInput(f"{cell.path}: [guard] fixtures: expected a list of tables")
    for n, fx in enumerate(fixtures):
        where = f"{cell.path}: [guard] fixtures[{n}]"
        name = fx.get("name") if isinstance(fx, dict) else None
        if not isinstance(name, str) or not name:
            raise BadInput(f"{where}: name: expected a non-empty string")
        T, half = _box_spec(where, fx)
        bodies.append(Body(FIXTURE, name, "box", T=T, half_mm=half))
    return GuardScene(arms, bodies, allowed_pairs(cell, table, bodies))


def allowed_pairs(cell, table: dict, bodies: list[Body]) -> set[frozenset]:
    """The ``[guard] allow`` table as a set of body-key pairs; an unknown arm or body is one line."""
    allow = table.get("allow", [])
    known = {b.key for b in bodies}
    owners = sorted({b.owner for b in bodies})
    out = set()
    if not isinstance(allow, list):
        raise BadInput(f"{cell.path}: [guard] allow: expected a list of [\"ARM.BODY\", \"ARM.BODY\"] pairs")
    for n, pair in enumerate(allow):
        if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(v, str) for v in pair)):
            raise BadInput(f"{cell.path}: [guard] allow[{n}]: expected [\"ARM.BODY\", \"ARM.BODY\"]")
        for key in pair:
            owner, _, body = key.partition(".")
            if owner not in owners:
                raise BadInput(f"{cell.path}: [guard] allow[{n}]: {key!r}: no arm or fixture {owner!r} "
                               f"(known: {', '.join(owners)})")
            if key not in known:
                have = ", ".join(b.name for b in bodies if b.owner == owner)
                raise BadInput(f"{cell.path}: [guard] allow[{n}]: {key!r}: {owner} has no body {body!r} (bodies: {have})")
        out.add(frozenset(pair))
    return out


def home_overlaps(scene: GuardScene, homes_deg: dict[str, np.ndarray]) -> Closest | None:
    """The closest pair when the arms at their home poses [deg] overlap outside the allowed table, else None."""
    c = scene.closest(homes_deg)
    return c if c.in_collision else None


def check_guard_homes(cell) -> None:
    """``droid-cell up``'s check of a cell with a ``[guard]`` table (docs/guard.md): the table is
    valid (one line otherwise) and no two bodies overlap with every arm at its home pose (the
    robot file's ``home_switch_deg``, where homing leaves it) outside the allowed pairs --
    :class:`BadInput`, one line naming the pair, before anything starts."""
    if "guard" not in cell.raw:
        return
    scene = guard_scene(cell)
    if not scene.pairs:
        return
    homes = {n: np.asarray(load_robot(cell.subunits[n].robot).home_switch_deg, float) for n in scene.arms}
    c = home_overlaps(scene, homes)
    if c is not None:
        raise BadInput(f"{cell.path}: [guard] {c.a.label()} and {c.b.label()} overlap at the arms' home poses "
                       f"({c.distance_mm:.1f} mm): move a base or a fixture, or allow the pair")

