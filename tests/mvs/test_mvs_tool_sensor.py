"""The measuring sensor virtually at the tool tip (thesis §6.1)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.sim.mvs.frames import rot_y, rot_z, translation
from droid.sim.mvs.tool_sensor import measure, pose_for_reading, seam_frame
from droid.sim.workpiece import load_workpiece

STEP = load_workpiece("step_input")
RAMP = load_workpiece("ramp_r300")


@pytest.mark.parametrize("wp,s", [(STEP, 50.0), (STEP, 400.0), (RAMP, 500.0), (RAMP, -20.0)])
def test_on_the_seam_every_deviation_is_zero(wp, s):
    m = measure(seam_frame(wp, s), wp)
    assert (m.lateral_mm, m.height_mm, m.roll_rad) == pytest.approx((0, 0, 0), abs=1e-9)
    assert m.s_mm == pytest.approx(s, abs=1e-6)


def test_offsets_in_the_tool_frame():
    # Tool tip 3 mm above the seam (-x) and 4 mm to its left in W (+y_tool).
    pose = seam_frame(STEP, 200.0) @ translation(-3.0, 4.0, 0.0)
    m = measure(pose, STEP)
    assert (m.height_mm, m.lateral_mm) == pytest.approx((3.0, -4.0))


@settings(max_examples=80, deadline=None)
@given(s=st.floats(20, 850), x=st.floats(-20, 20), y=st.floats(-20, 20), roll=st.floats(-0.5, 0.5))
def test_pose_for_reading_and_measure_agree(s, x, y, roll):
    m = measure(pose_for_reading(RAMP, s, x, y, roll), RAMP)
    assert (m.height_mm, m.lateral_mm, m.roll_rad) == pytest.approx((x, y, roll), abs=1e-6)
    assert m.s_mm == pytest.approx(s, abs=1e-6)


def test_yawed_tool_measures_where_its_sheet_crosses_the_seam():
    # Yaw (about the tool x, the tool axis) by 0.2 rad, 10 mm lateral: the sheet
    # crosses the seam 10/tan... the lateral stays the perpendicular-in-sheet distance.
    pose = seam_frame(STEP, 300.0) @ translation(0.0, 10.0, 0.0)
    yawed = pose @ np.array([[1, 0, 0, 0], [0, math.cos(0.2), -math.sin(0.2), 0],
                             [0, math.sin(0.2), math.cos(0.2), 0], [0, 0, 0, 1]])
    m = measure(yawed, STEP)
    assert m.lateral_mm == pytest.approx(-10.0 / math.cos(0.2))
    assert m.s_mm == pytest.approx(300.0 - 10.0 * math.tan(0.2))
    assert m.height_mm == pytest.approx(0.0, abs=1e-9)


def test_pitch_moves_the_height_not_the_roll():
    m = measure(seam_frame(STEP, 300.0) @ translation(-5.0, 0, 0) @ rot_y(0.3), STEP)
    assert m.height_mm == pytest.approx(5.0 / math.cos(0.3))
    assert m.roll_rad == pytest.approx(0.0, abs=1e-12) and m.lateral_mm == pytest.approx(0.0, abs=1e-9)


def test_roll_of_the_tool_is_minus_surface_roll():
    m = measure(seam_frame(STEP, 300.0) @ rot_z(0.25), STEP)
    assert m.roll_rad == pytest.approx(-0.25)


def test_no_crossing_when_the_sheet_runs_along_the_seam():
    along = seam_frame(STEP, 300.0) @ np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]]) \
        @ translation(0.0, 0.0, 5.0)  # the sheet parallel to the seam, 5 mm beside it
    assert measure(along, STEP) is None
