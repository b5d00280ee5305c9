"""The seam tracker's nearest-segment search compiled (droid/_kernel.c ``seam_nearest``, issue 44)
against the numpy reference (droid.tasks.seam.core.nearest_segment), bit for bit.

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
from droid.tasks.seam.core import SeamPatch, SeamTracker, nearest_segment


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
