"""The guard's distances against coal's (the Flexible Collision Library's successor; issue 41).

The bodies come from the URDF ``droid-kin urdf`` writes (:func:`droid.kinematics.urdf.robot_urdf`
with the cell's tool and sensor mounts), read by yourdfpy: each link's collision elements
(a cylinder with a sphere at each end is a capsule, a lone sphere a ball, the sensor a box) as
coal shapes, placed by a forward kinematics of the URDF's own joints (origin, axis) that this
test computes -- checked against yourdfpy's on a few configurations.  10,000 random joint
vectors of the two arms of cells/sim.toml (within their limits): the least distance over every
pair of bodies of the two arms agrees with the guard's within 0.1 mm where the arms are apart,
and both say "in collision" for the same configurations.  The URDF's base discs are not guard
bodies (docs/guard.md) and are left out here too.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

coal = pytest.importorskip("coal", reason="coal is in the test extra (pyproject.toml)")
yourdfpy = pytest.importorskip("yourdfpy", reason="yourdfpy is in the test extra (pyproject.toml)")

from droid.brain.cell.cellfile import load_cell  # noqa: E402
from droid.guard.cell import GuardScene, guard_scene  # noqa: E402
from droid.kinematics import load_robot  # noqa: E402
from droid.kinematics.cli import cell_mounts  # noqa: E402
from droid.kinematics.transforms import pose_to_T  # noqa: E402
from droid.kinematics.urdf import robot_urdf  # noqa: E402

CELL = Path(__file__).resolve().parents[2] / "cells" / "sim.toml"
N = 10_000
TOL_MM = 0.1


def _rodrigues(axis, q):
    """(N, 4, 4) rotations about a unit axis by angles q (N,) [rad]."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(q)[:, None, None], np.cos(q)[:, None, None]
    T = np.tile(np.eye(4), (len(q), 1, 1))
    T[:, :3, :3] = np.eye(3) + s * K + (1.0 - c) * (K @ K)
    return T


class UrdfArm:
    """A URDF's collision shapes as coal objects and a batched FK of its joints (m, rad)."""

    def __init__(self, text: str, base_mm: np.ndarray) -> None:
        self.urdf = yourdfpy.URDF.load(io.StringIO(text), load_meshes=False, build_collision_scene_graph=False)
        self.base = base_mm.copy()
        self.base[:3, 3] *= 1e-3
        self.joints = []  # (parent, child, origin, axis or None, index of q)
        by_parent = {}
        for j in self.urdf.robot.joints:
            by_parent.setdefault(j.parent, []).append(j)
        order, todo = [], ["base_link"]
        while todo:
            link = todo.pop(0)
            for j in by_parent.get(link, []):
                order.append(j)
                todo.append(j.child)
        names = self.urdf.actuated_joint_names
        for j in order:
            k = names.index(j.name) if j.type == "revolute" else None
            self.joints.append((j.parent, j.child, np.asarray(j.origin, float), np.asarray(j.axis, float), k))
        self.shapes = []  # (link, coal shape, T_link_shape, name)
        for name, link in self.urdf.link_map.items():
            if name == "base_link":
                continue
            cols = link.collisions
            cyl = [c for c in cols if c.geometry.cylinder is not None]
            box = [c for c in cols if c.geometry.box is not None]
            sph = [c for c in cols if c.geometry.sphere is not None]
            if cyl:  # cylinder + its end spheres: a capsule along the cylinder's z
                g = cyl[0].geometry.cylinder
                self.shapes.append((name, coal.Capsule(g.radius, g.length), np.asarray(cyl[0].origin, float)))
            elif box:
                self.shapes.append((name, coal.Box(*box[0].geometry.box.size), np.asarray(box[0].origin, float)))
            elif sph:
                self.shapes.append((name, coal.Sphere(sph[0].geometry.sphere.radius), np.asarray(sph[0].origin, float)))

    def link_frames(self, q_rad: np.ndarray) -> dict[str, np.ndarray]:
        n = q_rad.shape[0]
        T = {"base_link": np.broadcast_to(self.base, (n, 4, 4))}
        for parent, child, origin, axis, k in self.joints:
            t = T[parent] @ origin
            T[child] = t @ _rodrigues(axis, q_rad[:, k]) if k is not None else t
        return T

    def shape_poses(self, q_rad):
        T = self.link_frames(q_rad)
        return [(name, shape, T[name] @ local) for name, shape, local in self.shapes]


def _tf(T):
    return coal.Transform3s(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]))


def _two_arms(gmf1_x_mm=None):
    cell = load_cell(CELL)
    if gmf1_x_mm is not None:  # the holder moved in along x: more near misses and collisions
        cell.subunits["gmf1"].base = [gmf1_x_mm, *cell.subunits["gmf1"].base[1:]]
    full = guard_scene(cell)
    arms = {}
    for name in full.arms:
        sub = cell.subunits[name]
        _, mounts = cell_mounts(cell.raw, name)
        text = robot_urdf(load_robot(sub.robot), tool=mounts.get("tool"), sensor=mounts.get("sensor"))
        arms[name] = UrdfArm(text, pose_to_T(*sub.base))
    # the guard's scene on the URDF's bodies: the arms only (no held workpiece, no fixture)
    arm_only = GuardScene(full.arms, [b for b in full.bodies if b.owner in full.arms and b.name != "workpiece"], set())
    return cell, arm_only, arms


@pytest.fixture(scope="module")
def two_arms():
    return _two_arms()


def _random_q(cell, rng, n):
    out = {}
    for name, sub in cell.subunits.items():
        if sub.is_arm and sub.robot:
            m = load_robot(sub.robot)
            out[name] = rng.uniform(m.joint_min_deg, m.joint_max_deg, size=(n, 6))
    return out


def test_urdf_fk_here_is_yourdfpys(two_arms):
    cell, _, arms = two_arms
    q = _random_q(cell, np.random.default_rng(5), 3)
    for name, arm in arms.items():
        mine = arm.link_frames(np.radians(q[name]))
        for i in range(3):
            arm.urdf.update_cfg(np.radians(q[name][i]))
            for link in ("link_3", "link_6", "tool0"):
                ref = arm.base @ arm.urdf.get_transform(link, "base_link")
                assert np.allclose(mine[link][i], ref, atol=1e-9)


def _agreement(cell, scene, arms, n, seed):
    """(guard's least distance, coal's) [mm] over n random configurations."""
    q = _random_q(cell, np.random.default_rng(seed), n)
    d_guard = scene.distances(q).min(axis=1)  # [mm]
    a, b = arms["arm1"], arms["gmf1"]
    pa, pb = a.shape_poses(np.radians(q["arm1"])), b.shape_poses(np.radians(q["gmf1"]))
    assert len(pa) * len(pb) == scene.n_pairs  # the same pairs: 8 bodies x 6 links
    req, res = coal.DistanceRequest(), coal.DistanceResult()
    d_coal = np.empty(n)
    for i in range(n):
        ta = [(s, _tf(T[i])) for _, s, T in pa]
        tb = [(s, _tf(T[i])) for _, s, T in pb]
        best = np.inf
        for s1, t1 in ta:
            for s2, t2 in tb:
                res.clear()
                best = min(best, coal.distance(s1, t1, s2, t2, req, res))
        d_coal[i] = best * 1000.0
    return d_guard, d_coal


@pytest.mark.parametrize("gmf1_x_mm,seed,min_hits", [(None, 41, 1), (1300.0, 42, 50)],
                         ids=["as-the-cell", "holder-at-1300mm"])
def test_guard_distances_equal_coals_on_10000_configurations(gmf1_x_mm, seed, min_hits):
    """5,000 configurations with the cell's bases and 5,000 with the holder 1300 mm from the welder."""
    cell, scene, arms = _two_arms(gmf1_x_mm)
    d_guard, d_coal = _agreement(cell, scene, arms, N // 2, seed)
    hit_g, hit_c = d_guard <= 0.0, d_coal <= 0.0
    assert np.array_equal(hit_g, hit_c), np.flatnonzero(hit_g != hit_c)[:10]
    apart = ~hit_g
    assert hit_g.sum() >= min_hits and apart.sum() > 1000  # both kinds drawn
    err = np.abs(d_guard[apart] - d_coal[apart])
    print(f"coal agreement ({gmf1_x_mm or 'cell'}): {apart.sum()} apart, {hit_g.sum()} in collision, "
          f"max |guard - coal| {err.max():.2e} mm, near (< 50 mm) {np.sum(d_coal[apart] < 50.0)}")
    assert err.max() < TOL_MM, (err.max(), np.argmax(err))
