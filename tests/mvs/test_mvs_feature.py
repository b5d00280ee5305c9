"""Feature extraction on synthetic lap-joint profiles against ground truth (thesis §5.4)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from droid.cli import BadInput
from droid.sim.mvs.camera import CameraNoise, lap_joint_profile_mm, quantise
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.feature import Feature, analyse, extract
from droid.subunits.mvs.wire import COLUMNS, ROWS

CAL = MvsCalibration()
CASES = 60


def random_cases(seed, noise, n=CASES, roll_max=0.25):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        x, y, roll = rng.uniform(-10, 10), rng.uniform(-15, 15), rng.uniform(-roll_max, roll_max)
        side = 1.0 if rng.random() < 0.5 else -1.0
        rows = quantise(lap_joint_profile_mm(CAL, x, y, roll, 2.0, side), CAL, noise, rng)
        yield rows, (x, y, roll)


# (jitter px, spurious fraction) -> (min detection rate, RMS row error px, RMS column error px)
GRID = {
    (0.0, 0.0): (1.0, 0.35, 0.15),
    (0.5, 0.0): (1.0, 0.35, 0.20),
    (1.0, 0.0): (1.0, 0.35, 0.30),
    (0.0, 0.1): (0.96, 0.50, 0.20),
    (0.5, 0.1): (0.96, 0.50, 0.25),
    (1.0, 0.1): (0.96, 0.50, 0.35),
}


@pytest.mark.parametrize("jitter,spurious", list(GRID))
def test_position_and_roll_against_ground_truth(jitter, spurious):
    min_rate, row_rms, col_rms = GRID[(jitter, spurious)]
    found, row_err, col_err = 0, [], []
    for rows, (x, y, roll) in random_cases(7, CameraNoise(jitter, spurious)):
        f = extract(rows, CAL)
        if f is None:
            continue
        found += 1
        # Never a wrong feature: every detection within 1 mm and 10 mrad.
        assert math.hypot(f.x_mm - x, f.y_mm - y) < 1.0
        assert abs(f.roll_rad - roll) < 0.01
        assert f.step_mm == pytest.approx(2.0, abs=0.2)
        row_err.append(f.row - CAL.row_of(y))
        col_err.append(f.column - CAL.column_of(x))
        # The pixel and mm outputs describe the same point.
        assert CAL.to_mm(f.row, f.column) == pytest.approx((f.x_mm, f.y_mm))
    assert found >= min_rate * CASES
    assert np.sqrt(np.mean(np.square(row_err))) <= row_rms
    assert np.sqrt(np.mean(np.square(col_err))) <= col_rms


def test_unrolled_step_exact_without_noise():
    # Foot half-way between rows 150 and 151, the lower surface on column 286.
    x, y = CAL.to_mm(150.5, 286.0)
    rows = quantise(lap_joint_profile_mm(CAL, x, y, 0.0, 2.0), CAL, CameraNoise(), np.random.default_rng(0))
    f = extract(rows, CAL)
    assert (f.row, f.column) == pytest.approx((150.5, 286.0), abs=1e-9)
    assert (f.x_mm, f.y_mm, f.roll_rad) == pytest.approx((x, y, 0.0), abs=1e-9)


@pytest.mark.parametrize("roll", [-0.35, -0.1, 0.1, 0.35])
@pytest.mark.parametrize("side", [1.0, -1.0])
def test_roll_sign_and_both_edge_cases(roll, side):
    """Positive roll: the profile comes nearer the sensor toward +y (x = -tan(roll) y).

    With one sign the laser sees the step's edge face, with the other the
    upper plate overhangs its foot; both must give the foot.
    """
    depth = lap_joint_profile_mm(CAL, 1.0, -2.0, roll, 2.0, side)
    ys = CAL.lateral_of(np.arange(ROWS))
    lower = np.isclose(depth, 1.0 - math.tan(roll) * (ys + 2.0))
    assert lower.sum() > 50  # sanity of the synthetic profile
    f = extract(quantise(depth, CAL, CameraNoise(0.3), np.random.default_rng(3)), CAL)
    assert f.roll_rad == pytest.approx(roll, abs=0.005)
    assert (f.x_mm, f.y_mm) == pytest.approx((1.0, -2.0), abs=0.15)


def no_feature(rows):
    result = analyse(np.asarray(rows, dtype=np.int16), CAL)
    return isinstance(result, str) and extract(np.asarray(rows, dtype=np.int16), CAL) is None


def test_empty_frame_is_invalid():
    assert no_feature(np.full(ROWS, -1))


def test_flat_surface_without_step_is_invalid():
    rng = np.random.default_rng(1)
    for roll in (0.0, 0.2):
        depth = 2.0 - math.tan(roll) * CAL.lateral_of(np.arange(ROWS, dtype=float))
        assert no_feature(quantise(depth, CAL, CameraNoise(0.5, 0.05), rng))
    assert "no step" in analyse(np.full(ROWS, 256, dtype=np.int16), CAL)


def test_all_spurious_rows_are_invalid():
    rng = np.random.default_rng(2)
    for _ in range(50):
        assert no_feature(rng.integers(0, COLUMNS, ROWS))


def test_too_small_a_step_is_invalid():
    rows = quantise(lap_joint_profile_mm(CAL, 0.0, 0.0, 0.0, 0.4), CAL, CameraNoise(0.3), np.random.default_rng(4))
    assert no_feature(rows)


def test_step_at_the_edge_of_the_view_is_invalid():
    rows = quantise(lap_joint_profile_mm(CAL, 0.0, CAL.lateral_of(5.5), 0.0, 2.0), CAL, CameraNoise(),
                    np.random.default_rng(0))
    assert no_feature(rows)


def test_non_parallel_lines_are_invalid():
    r = np.arange(ROWS)
    rows = np.where(r < 120, 256 + 0.02 * (r - 120), 236 - 1.2 * (r - 120))
    assert no_feature(np.rint(rows))


def test_half_a_frame_missing_is_invalid():
    rows = quantise(lap_joint_profile_mm(CAL, 0.0, 0.0, 0.0, 2.0), CAL, CameraNoise(), np.random.default_rng(0))
    rows[:125] = -1
    assert no_feature(rows)


def test_wrong_frame_shape_is_bad_input():
    with pytest.raises(BadInput, match="240 rows"):
        extract(np.zeros(239, np.int16), CAL)


@settings(max_examples=200, deadline=None)
@given(arrays(np.int16, ROWS, elements=st.integers(-5, COLUMNS + 5)))
def test_any_frame_gives_a_feature_or_none_never_an_exception(rows):
    f = extract(rows, CAL)
    assert f is None or (isinstance(f, Feature) and all(
        math.isfinite(v) for v in (f.x_mm, f.y_mm, f.roll_rad, f.row, f.column)))


@settings(max_examples=60, deadline=None)
@given(x=st.floats(-15, 15), y=st.floats(-15, 15), roll=st.floats(-0.3, 0.3), side=st.sampled_from([1.0, -1.0]),
       seed=st.integers(0, 2**31))
def test_clean_profiles_anywhere_in_view_are_found(x, y, roll, side, seed):
    rows = quantise(lap_joint_profile_mm(CAL, x, y, roll, 2.0, side), CAL, CameraNoise(0.5),
                    np.random.default_rng(seed))
    f = extract(rows, CAL)
    assert f is not None
    assert math.hypot(f.x_mm - x, f.y_mm - y) < 0.35 and abs(f.roll_rad - roll) < 0.01


def _reference_module():
    """tests/mvs/feature_reference.py: the extraction as it was before the speed work (np.median etc.)."""
    import importlib.util
    import sys
    from pathlib import Path

    name = "tests_mvs_feature_reference"
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("feature_reference.py"))
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


REFERENCE = _reference_module()


@settings(max_examples=150, deadline=None)
@given(x=st.floats(-12, 12), y=st.floats(-22, 22), roll=st.floats(-0.8, 0.8), step=st.floats(0.3, 7.0),
       side=st.sampled_from([1.0, -1.0]), jitter=st.floats(0.0, 2.0), spurious=st.floats(0.0, 0.3),
       seed=st.integers(0, 2**31))
def test_extraction_is_the_reference_bit_for_bit(x, y, roll, step, side, jitter, spurious, seed):
    """The optimised medians and step location give the straightforward form's results exactly
    (the feature or the reason there is none), on clean, noisy, spurious, rolled and odd-step frames."""
    rows = quantise(lap_joint_profile_mm(CAL, x, y, roll, step, side), CAL, CameraNoise(jitter, spurious),
                    np.random.default_rng(seed))
    assert repr(analyse(rows, CAL)) == repr(REFERENCE.analyse(rows, CAL))


@settings(max_examples=100, deadline=None)
@given(arrays(np.int16, ROWS, elements=st.integers(-5, COLUMNS + 5)))
def test_extraction_of_any_frame_is_the_reference(rows):
    assert repr(analyse(rows, CAL)) == repr(REFERENCE.analyse(rows, CAL))
