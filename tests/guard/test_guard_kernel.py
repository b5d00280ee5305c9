"""The compiled distance pass (droid._guard) against its Python reference (issue 41 item 5).

The reference (GuardScene.distances_reference, droid.guard.distance) is the specification: on
random configurations of every shipped cell and of the bench's scene (two fixtures, so box-box
pairs too) the compiled pass gives every pair's distance within 1e-9 mm, and the same least pair;
without the extension (or with DROID_GUARD_KERNEL=python) the reference runs.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from droid.brain.cell.cellfile import BUNDLED_CELLS, load_cell
from droid.guard import kernel
from droid.guard.cell import guard_scene

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.skipif(kernel._guard is None, reason="droid._guard is not built")


def scenes():
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_guard import bench_scene

    out = {c: guard_scene(load_cell(BUNDLED_CELLS / c)) for c in ("sim.toml", "abb_weld.toml", "reis_pair.toml")}
    out["bench (two fixtures)"] = bench_scene()
    return out


@pytest.mark.parametrize("name", ["sim.toml", "abb_weld.toml", "reis_pair.toml", "bench (two fixtures)"])
def test_the_compiled_pass_agrees_with_the_reference_on_random_configurations(name):
    scene = scenes()[name]
    assert scene.compiled is not None
    kinds = {a.kind[0] + b.kind[0] for a, b in scene.pairs}
    q = kernel.random_configs(scene, 2000, seed=7)
    # and configurations where bodies touch and overlap: each arm near the other's base
    ref, got = scene.distances_reference(q), scene.distances(q)
    assert got.shape == ref.shape == (2000, scene.n_pairs)
    assert float(np.max(np.abs(got - ref))) <= kernel.AGREE_MM
    assert np.array_equal(ref <= 0.0, got <= 0.0)  # the same verdict, pair by pair
    assert (ref <= 0.0).any() and (ref > 0.0).any()  # both kinds were drawn
    if name.startswith("bench"):
        assert kinds == {"cc", "cb", "bb"}
    one = {n: v[17] for n, v in q.items()}
    c = scene.closest(one)
    k = int(np.argmin(ref[17]))
    assert (c.a.key, c.b.key) == (scene.pairs[k][0].key, scene.pairs[k][1].key)


def _on_body(body, pts, p0, p1, bc, bR) -> np.ndarray:
    """How far [mm] points (B, 3) lie off a body: a capsule's axis segment, a box's volume."""
    from droid.guard import distance as D

    if body.kind == "capsule":
        return D.segment_segment(p0, p1, pts, pts)
    local = np.einsum("bji,bj->bi", bR, pts - bc)
    return D.point_box(local, np.broadcast_to(body.half_mm, local.shape))


@pytest.mark.parametrize("name", ["sim.toml", "abb_weld.toml", "reis_pair.toml", "bench (two fixtures)"])
def test_the_compiled_closest_points_agree_with_the_reference(name):
    """The closest points (the guard's direction between a pair, docs/guard.md §5): the same as the
    reference's on 2,000 random configurations (1e-6 mm), on their bodies, and as far apart as the
    pair's distance says (a capsule's point on its axis: the distance plus both radii)."""
    scene = scenes()[name]
    q = kernel.random_configs(scene, 2000, seed=11)
    ref, ra, rb = scene.closest_points_reference(q)
    got, ga, gb = scene.closest_points(q)
    assert float(np.max(np.abs(got - ref))) <= kernel.AGREE_MM
    assert np.array_equal(got, scene.distances(q))  # the two calls of the compiled pass: the same bits
    assert float(np.max(np.abs(ga - ra))) <= kernel.AGREE_POINT_MM
    assert float(np.max(np.abs(gb - rb))) <= kernel.AGREE_POINT_MM
    radii = np.array([a.radius_mm + b.radius_mm for a, b in scene.pairs])
    apart = got > 0.0
    sep = np.linalg.norm(gb - ga, axis=2) - radii
    assert float(np.max(np.abs(sep - got)[apart])) < 1e-6
    p0, p1, bc, bR = scene._poses(q)
    cap = {id(b): i for i, b in enumerate(scene.caps)}
    box = {id(b): i for i, b in enumerate(scene.boxes)}
    for k, pair in enumerate(scene.pairs):
        for body, pts in zip(pair, (ga[:, k], gb[:, k])):
            i = cap.get(id(body), box.get(id(body)))
            off = (_on_body(body, pts, p0[:, i], p1[:, i], None, None) if body.kind == "capsule"
                   else _on_body(body, pts, None, None, bc[:, i], bR[:, i]))
            assert float(np.max(off)) < 1e-6, (pair[0].key, pair[1].key, body.key)


def test_a_scene_without_the_extension_runs_the_reference(monkeypatch):
    monkeypatch.setattr(kernel, "_guard", None)
    scene = guard_scene(load_cell(BUNDLED_CELLS / "sim.toml"))
    assert scene.compiled is None
    q = kernel.random_configs(scene, 10, seed=1)
    assert np.array_equal(scene.distances(q), scene.distances_reference(q))
    assert all(np.array_equal(a, b) for a, b in zip(scene.closest_points(q), scene.closest_points_reference(q)))


def test_a_compiled_pass_without_closest_points_is_not_used():
    """An extension built before the closest points (an old droid/_guard*.so): the reference runs."""
    scene = guard_scene(load_cell(BUNDLED_CELLS / "sim.toml"))

    class Old:
        def distances(self, q, out):
            out[...] = 0.0

    assert "no closest points" in kernel.why_not(scene, Old())


def test_droid_guard_kernel_chooses():
    code = ("from droid.brain.cell.cellfile import BUNDLED_CELLS, load_cell; from droid.guard.cell import guard_scene; "
            "print(guard_scene(load_cell(BUNDLED_CELLS / 'sim.toml')).compiled is not None)")
    for choice, want in (("python", "False"), ("c", "True"), ("auto", "True")):
        out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                             env=dict(os.environ, DROID_GUARD_KERNEL=choice))
        assert out.returncode == 0 and out.stdout.strip() == want, (choice, out.stderr)
    out = subprocess.run([sys.executable, "-c", "import droid.guard.kernel"], cwd=ROOT, capture_output=True,
                         text=True, env=dict(os.environ, DROID_GUARD_KERNEL="fast"))
    assert out.returncode != 0 and "DROID_GUARD_KERNEL='fast'" in out.stderr


def test_a_malformed_scene_is_refused():
    with pytest.raises(ValueError, match="arm_data"):
        kernel._guard.Scene(1, np.zeros(3), np.zeros(0, np.int32), np.zeros(0), np.zeros(0, np.int32), np.zeros(0),
                            np.zeros(3, np.int32))
    scene = guard_scene(load_cell(BUNDLED_CELLS / "reis_pair.toml"))
    with pytest.raises(ValueError, match="q must hold"):
        scene.compiled.distances(np.zeros(5), np.zeros(scene.n_pairs))
