"""The seam tracker's nearest-segment search compiled (droid/_kernel.c ``seam_nearest``, issue 44)
against the numpy reference (droid.tasks.seam.patch.nearest_segment), bit for bit.

The kernel adds each row's three products in the order numpy's ``einsum`` does on this CPU
(droid.experiments.seam_kernel finds which and refuses the kernel where none matches); the
tolerance is zero: the same segment and the same foot's bytes, on patches as the tracker's
SeamPatch holds them (a slow trial's ~2000 frames, short segments, the tool on a point), and a
trial's log the same bytes with the reference or the kernel.  Like the plant's kernel these tests
fail, not skip, where the extension is not built."""
from __future__ import annotations

import numpy as np
import pytest

from droid import kernel
from droid.experiments import seam_kernel
from droid.tasks.seam.core import SeamTracker
from droid.tasks.seam.patch import SeamPatch, nearest_segment


def test_the_kernel_is_chosen_here():
    if kernel.NAME == "python":
        pytest.skip("DROID_KERNEL=python: the reference runs")
    assert seam_kernel.nearest_segment() is not None, "droid._kernel.seam_nearest matches no einsum order"


def _patch(rng, n, spacing):
    patch = SeamPatch()
    p = rng.uniform(-500, 500, 3)
    for _ in range(n):
        p = p + rng.standard_normal(3) * spacing * (rng.random() > 0.1)  # a tenth repeat the last point
        patch.push_front(tuple(p.tolist()))
    return patch


@pytest.mark.parametrize("seed", range(6))
def test_compiled_search_gives_the_references_bits_on_seam_patches(seed):
    fast = seam_kernel.nearest_segment()
    if fast is None:
        pytest.skip("the reference runs (DROID_KERNEL=python)")
    rng = np.random.default_rng(seed)
    patch = _patch(rng, int(rng.integers(2, 2200)), 10.0 ** rng.uniform(-3, 0.5))
    P = patch.array
    for i in range(60):
        tool = P[int(rng.integers(0, len(P)))] + (rng.standard_normal(3) * 10.0 ** rng.uniform(-6, 1) if i % 4 else 0)
        T = np.eye(4)
        T[:3, 3] = tool
        tool = T[:3, 3]  # a column of a 4x4, as the tracker's Ttool7_hold gives it (not contiguous)
        args = (tool, P[1:], *patch.segments())
        j, want = nearest_segment(*args)
        k, got = fast(*args)
        assert k == j and got.tobytes() == want.tobytes(), (i, k, j)


def test_the_tracker_takes_the_checked_search_or_keeps_the_reference():
    assert SeamTracker.nearest is nearest_segment or SeamTracker.nearest.__func__ is nearest_segment


def test_a_trials_log_is_the_same_bytes_with_the_kernel_or_the_reference(monkeypatch):
    from droid.experiments.trial import TrialConfig, run_trial

    cfg = TrialConfig("k44", "i", 8.0, length_mm=60, seed=2, arm="fast", sensor="ideal")
    fast = run_trial(cfg)
    monkeypatch.setattr(seam_kernel, "use_on", lambda tracker: False)
    ref = run_trial(cfg)
    assert len(fast.rows) > 50
    assert repr(fast.rows) == repr(ref.rows) and fast.stop_reason == ref.stop_reason


# -- the pose interpolation of the tracking cycle's histories (droid/_kernel.c ``pose_interp``, h50) --

def test_the_pose_kernel_is_chosen_here():
    if kernel.NAME == "python":
        pytest.skip("DROID_KERNEL=python: the reference runs")
    assert seam_kernel.pose_interpolation() is not None, "droid._kernel.pose_interp matches no BLAS order"


def _status_pose(rng, T=None, angle_rad=None):
    """A Status-like pose [mm]: a rotation (a little off orthonormal, as a record's R may be) and a
    position; near ``T`` (``angle_rad`` apart) when given."""
    from droid.tasks.seam.cycle import _rot_exp

    axis = rng.standard_normal(3)
    angle = rng.uniform(0, np.pi) if angle_rad is None else angle_rad
    R = _rot_exp(axis / np.linalg.norm(axis) * angle)
    out = np.eye(4)
    if T is None:
        out[:3, :3] = R + rng.standard_normal((3, 3)) * 1e-12
        out[:3, 3] = rng.uniform(-2000, 2000, 3)
    else:
        out[:3, :3] = T[:3, :3] @ R
        out[:3, 3] = T[:3, 3] + rng.standard_normal(3) * 10.0 ** rng.uniform(-4, 1)
    return out


@pytest.mark.parametrize("seed", range(8))
def test_compiled_interpolation_gives_the_references_bits_on_random_poses(seed):
    from droid.tasks.seam.cycle import interpolate_pose

    fast = seam_kernel.pose_interpolation()
    if fast is None:
        pytest.skip("the reference runs (DROID_KERNEL=python)")
    rng = np.random.default_rng(1000 + seed)
    for i in range(200):
        T0 = _status_pose(rng)
        if i % 9 == 0:
            T1 = T0.copy()  # the holder at rest: the same pose twice
        else:
            T1 = _status_pose(rng, T0, (np.pi - 1e-7) if i % 9 == 1 else 10.0 ** rng.uniform(-14, 0.4))
        u = float(rng.random()) if i % 5 else (0.0, 1.0, 0.25, 0.75, 0.5)[i % 25 // 5]
        want, got = interpolate_pose(T0, T1, u), fast(T0, T1, u)
        assert got.tobytes() == want.tobytes(), (i, got - want)


def test_a_pose_history_reads_the_same_bits_with_the_compiled_interpolation():
    from droid.tasks.seam.cycle import PoseHistory

    fast = seam_kernel.pose_interpolation()
    if fast is None:
        pytest.skip("the reference runs (DROID_KERNEL=python)")
    rng = np.random.default_rng(7)
    ref, comp = PoseHistory(), PoseHistory()
    comp.interpolate = fast
    T = _status_pose(rng)
    for tick in range(300):
        T = _status_pose(rng, T, 10.0 ** rng.uniform(-6, -2)) if tick % 4 else T
        ref.add(tick - 0.75, T)
        comp.add(tick - 0.75, T)
        t = tick - 0.75 - rng.uniform(0, 20)
        a, b = ref.at(t), comp.at(t)
        assert (a is None and b is None) or a.tobytes() == b.tobytes(), tick
    assert PoseHistory.interpolate is not fast  # the class keeps the reference


def test_a_trials_log_is_the_same_bytes_with_the_compiled_interpolation_or_the_reference(monkeypatch):
    from droid.experiments.trial import TrialConfig, run_trial

    if seam_kernel.pose_interpolation() is None:
        pytest.skip("the reference runs (DROID_KERNEL=python)")
    used = []
    real = seam_kernel.use_on_cycle
    monkeypatch.setattr(seam_kernel, "use_on_cycle", lambda cyc: used.append(real(cyc)) or used[-1])
    cfg = TrialConfig("k50", "i", 8.0, length_mm=60, seed=3, arm="fast", sensor="ideal")
    fast = run_trial(cfg)
    monkeypatch.setattr(seam_kernel, "use_on_cycle", lambda cyc: False)
    ref = run_trial(cfg)
    assert used == [True] and len(fast.rows) > 50
    assert repr(fast.rows) == repr(ref.rows) and fast.stop_reason == ref.stop_reason
    assert repr(fast.tool_seam_mm) == repr(ref.tool_seam_mm)
