"""Encoder gearing and coupling (thesis eq. 4.10-4.14) and 16-bit roll-over (§4.1.5.1)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.kinematics import Gearing, extend_counter, extend_counters

joint_vec = st.lists(st.floats(-400.0, 400.0, allow_nan=False), min_size=6, max_size=6)


def test_reis_counts_per_degree_reads_the_text(reis):
    # 100:1 harmonic drive x 4000 counts/rev / 360 deg (eq. 4.10 read as in the text)
    assert np.allclose(reis.gearing.counts_per_deg, 100 * 4000 / 360)
    assert reis.gearing.encoder_bits == 16


def test_reis_coupling_solves_eq_4_11_to_4_14_simultaneously(reis):
    g = 100 * 4000 / 360
    rng = np.random.default_rng(1)
    for q in rng.uniform(-150, 150, (50, 6)):
        m = reis.gearing.joints_to_counts(q)
        assert m[0] == pytest.approx(-q[0] * g)  # j1 = -j1_ang * G
        assert m[1] == pytest.approx(q[1] * g + m[2] / 100)  # eq. 4.11
        assert m[2] == pytest.approx(q[2] * g + m[1] / 100)  # eq. 4.12
        assert m[3] == pytest.approx(-q[3] * g + m[4] / 100)  # eq. 4.13
        assert m[4] == pytest.approx(q[4] * g - m[3] / 100)  # eq. 4.14
        assert m[5] == pytest.approx(q[5] * g)


def test_matrices_are_inverse_and_read_only(reis):
    g = reis.gearing
    assert np.allclose(g.joint_to_counts_matrix @ g.counts_to_joint_matrix, np.eye(6), atol=1e-12)
    with pytest.raises(ValueError):
        g.joint_to_counts_matrix[0, 0] = 1.0


@settings(max_examples=300, deadline=None)
@given(joint_vec)
def test_property_exact_round_trip(q):
    from droid.kinematics import load_robot

    for name in ("reis_v15", "fanuc_s400"):
        g = load_robot(name).gearing
        back = g.counts_to_joints(g.joints_to_counts(q))
        assert np.allclose(back, q, rtol=0, atol=1e-9)
        c = np.array(q) * 1000.0
        assert np.allclose(g.joints_to_counts(g.counts_to_joints(c)), c, rtol=0, atol=1e-6)


def test_integer_counts_round_trip_within_half_a_count(reis):
    rng = np.random.default_rng(2)
    q = rng.uniform(-150, 150, (100, 6))
    c = reis.gearing.joints_to_counts_int(q)
    assert c.dtype == np.int64
    assert np.all(np.abs(c - reis.gearing.joints_to_counts(q)) <= 0.5)


def test_batched_shapes(reis):
    q = np.zeros((4, 3, 6))
    assert reis.gearing.joints_to_counts(q).shape == (4, 3, 6)


def test_from_table_validation():
    ok = {"reduction": 100, "encoder_counts_per_rev": 4000}
    assert np.allclose(Gearing.from_table(ok).counts_per_deg, 100 * 4000 / 360)
    for bad in (
        {"reduction": 100},
        {"reduction": -1, "encoder_counts_per_rev": 4000},
        {"reduction": 100, "encoder_counts_per_rev": 4000, "direction": [1, 1, 1]},
        {"reduction": 100, "encoder_counts_per_rev": 4000, "direction": [1, 2, 1, 1, 1, 1]},
        {"reduction": 100, "encoder_counts_per_rev": 4000, "coupling": np.eye(6).tolist()},
        {"reduction": "x", "encoder_counts_per_rev": 4000},
    ):
        with pytest.raises(ValueError):
            Gearing.from_table(bad)


# ---------------------------------------------------------------- roll-over


def test_extend_counter_examples():
    assert extend_counter(65530, 4) == 65540  # forward through the wrap
    assert extend_counter(4, 65530) == -6  # backward through the wrap
    assert extend_counter(-70000, (-70000 - 5) % 65536) == -70005
    assert extend_counter(0, 1 << 15) == -(1 << 15)  # exactly half: read as backwards


@settings(max_examples=300, deadline=None)
@given(
    st.integers(-(2**40), 2**40),
    st.lists(st.integers(-(2**15) + 1, 2**15 - 1), min_size=1, max_size=200),
    st.sampled_from([16, 24]),
)
def test_property_extend_counter_follows_an_unbounded_walk(start, steps, bits):
    span = 1 << bits
    steps = [s % span if s >= 0 else -((-s) % span) for s in steps]
    true = start
    ext = start
    for s in steps:
        true += s
        raw = true % span  # what a bits-wide hardware counter shows
        ext = extend_counter(ext, raw, bits)
        assert ext == true
    assert extend_counters([start, true], [start % span, true % span], bits).tolist() == [start, true]


def test_extend_counters_vector_form():
    prev = np.array([65530, 4, 0, -5, 100, 32767])
    raw = np.array([4, 65530, 1, 65530, 90, 32768])
    got = extend_counters(prev, raw, 16)
    assert got.tolist() == [extend_counter(int(p), int(r)) for p, r in zip(prev, raw)]
