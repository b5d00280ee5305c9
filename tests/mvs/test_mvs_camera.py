"""The camera/DSP twin over the thesis workpieces, end to end with the feature core."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.sim.mvs.camera import CameraNoise, MvsCamera
from droid.sim.mvs.frames import rot_y, translation
from droid.sim.mvs.tool_sensor import measure, pose_for_reading, seam_frame
from droid.sim.workpiece import load_workpiece
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.feature import extract
from droid.subunits.mvs.wire import ROWS

STEP = load_workpiece("step_input")
CAL = MvsCalibration()


def read(camera, pose, seed=0):
    rows = camera.frame(pose, np.random.default_rng(seed))
    return rows, extract(rows, CAL)


def test_frame_is_240_int16_columns():
    rows = MvsCamera(STEP).frame(seam_frame(STEP, 50.0), np.random.default_rng(0))
    assert rows.dtype == np.int16 and rows.shape == (ROWS,)
    assert rows.min() >= 0 and rows.max() < 512  # the whole view sees the track


@pytest.mark.parametrize("offset_mm", [-12.0, -3.0, 0.0, 4.0, 15.0])
def test_lateral_offset_of_the_sensor_is_reported(offset_mm):
    """Moving the sensor by +d along its y puts the seam at y = -d."""
    camera = MvsCamera(STEP, noise=CameraNoise(0.5, 0.1))
    pose = seam_frame(STEP, 300.0) @ translation(0.0, offset_mm, 0.0)
    _, f = read(camera, pose, seed=int(offset_mm) + 20)
    assert f.y_mm == pytest.approx(-offset_mm, abs=0.25)
    assert f.x_mm == pytest.approx(0.0, abs=0.05)
    assert f.roll_rad == pytest.approx(0.0, abs=0.005)


@pytest.mark.parametrize("lift_mm", [-8.0, 5.0])
def test_stand_off_error_is_reported_as_depth(lift_mm):
    """Raising the sensor (toward +z_W = -x_S) puts the surface farther: x = +lift."""
    camera = MvsCamera(STEP, noise=CameraNoise(0.5))
    pose = translation(0.0, 0.0, lift_mm) @ seam_frame(STEP, 40.0)
    _, f = read(camera, pose)
    assert f.x_mm == pytest.approx(lift_mm, abs=0.05)
    assert f.y_mm == pytest.approx(0.0, abs=0.15)


@pytest.mark.parametrize("roll", [-0.3, -0.1, 0.15, 0.3])
def test_rolling_the_workpiece_is_reported_as_roll(roll):
    """Rolling the workpiece by +r about the seam (left side up) reads roll = +r."""
    camera = MvsCamera(STEP, noise=CameraNoise(0.5, 0.1))
    seam = seam_frame(STEP, 500.0)
    # The sensor stays; the workpiece turns about the seam line: T_W_S = Rx_seam(-r) @ seam.
    heading_axis = seam[0:3, 2]
    turn = np.eye(4)
    turn[0:3, 0:3] = _axis_angle(heading_axis, -roll)
    p = seam[0:3, 3]
    turn[0:3, 3] = p - turn[0:3, 0:3] @ p
    pose = turn @ seam
    _, f = read(camera, pose, seed=5)
    assert f.roll_rad == pytest.approx(roll, abs=0.005)
    # One frame, 10 % spurious rows: within a row and a quarter (0.2 mm a row).
    assert (f.x_mm, f.y_mm) == pytest.approx((0.0, 0.0), abs=0.25)
    truth = measure(pose, STEP)
    assert truth.roll_rad == pytest.approx(roll, abs=1e-9)


def _axis_angle(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


@pytest.mark.parametrize("name,s_mm", [("ramp_r200", 450.0), ("ramp_r500", 600.0), ("step_input", 101.0)])
def test_camera_then_extract_agrees_with_geometry_on_curves(name, s_mm):
    wp = load_workpiece(name)
    camera = MvsCamera(wp, noise=CameraNoise(0.5, 0.1))
    rng = np.random.default_rng(9)
    for _ in range(10):
        pose = pose_for_reading(wp, s_mm, rng.uniform(-8, 8), rng.uniform(-12, 12), rng.uniform(-0.2, 0.2))
        truth = measure(pose, wp)
        f = extract(camera.frame(pose, rng), CAL)
        assert f is not None
        assert (f.x_mm, f.y_mm) == pytest.approx((truth.height_mm, truth.lateral_mm), abs=0.25)
        assert f.roll_rad == pytest.approx(truth.roll_rad, abs=0.01)


def test_pitched_sensor_still_sees_the_seam():
    """Tilting the sensor about its y (pitch) leaves y and roll; x follows the geometry."""
    camera = MvsCamera(STEP, noise=CameraNoise(0.5))
    pose = seam_frame(STEP, 300.0) @ translation(0, 2.0, 0) @ np.array(
        [[math.cos(0.3), 0, math.sin(0.3), 0], [0, 1, 0, 0], [-math.sin(0.3), 0, math.cos(0.3), 0], [0, 0, 0, 1]])
    truth = measure(pose, STEP)
    _, f = read(camera, pose)
    assert (f.x_mm, f.y_mm, f.roll_rad) == pytest.approx((truth.height_mm, truth.lateral_mm, truth.roll_rad),
                                                         abs=0.15)


def test_off_the_track_there_is_no_stripe():
    camera = MvsCamera(STEP)
    rows, f = read(camera, seam_frame(STEP, 300.0) @ translation(0.0, 120.0, 0.0))
    assert (rows == -1).all() and f is None
    rows, f = read(camera, seam_frame(STEP, -40.0))  # before the lead-in
    assert (rows == -1).all() and f is None
    # Looking up, away from the surfaces.
    rows, _ = read(camera, seam_frame(STEP, 300.0) @ rot_y(math.pi))
    assert (rows == -1).all()


def test_near_the_track_edge_only_part_of_the_view_has_a_stripe():
    camera = MvsCamera(STEP)
    rows, _ = read(camera, seam_frame(STEP, 300.0) @ translation(0.0, 40.0, 0.0))  # upper edge at +50
    assert 0 < (rows >= 0).sum() < ROWS


def test_noise_is_seeded_and_shaped_by_its_parameters():
    pose = seam_frame(STEP, 200.0)
    clean = MvsCamera(STEP).frame(pose, np.random.default_rng(0))
    noisy = MvsCamera(STEP, noise=CameraNoise(1.0, 0.1, 0.0))
    a, b = noisy.frame(pose, np.random.default_rng(42)), noisy.frame(pose, np.random.default_rng(42))
    assert np.array_equal(a, b)
    diff = np.abs(a.astype(int) - clean)
    assert 0.02 < np.mean(diff > 5) < 0.2  # about 10 % spurious rows
    assert 0 < np.mean((diff > 0) & (diff <= 4)) < 0.8  # jitter moves some columns by a pixel or more
    assert MvsCamera(STEP, noise=CameraNoise(drop_probability=1.0)).frame(pose, np.random.default_rng(0)) is None
    rng = np.random.default_rng(1)
    dropped = sum(MvsCamera(STEP, noise=CameraNoise(drop_probability=0.25)).frame(pose, rng) is None
                  for _ in range(400))
    assert 60 < dropped < 140


def test_calibration_maps_the_field_of_view():
    assert CAL.to_mm(0, 0)[1] == pytest.approx(-23.9) and CAL.to_mm(239, 511) == pytest.approx((25.55, 23.9))
    assert CAL.slope_to_roll(2.0) == pytest.approx(-math.atan(1.0))  # 2 columns a row = 0.2 mm per 0.2 mm


def reference_profile_mm(camera, T_W_S):
    """MvsCamera.profile_mm in its straightforward form (before the speed work): every segment
    projected for every hit through Workpiece.nearest_many, the heights through heights_from."""
    from droid.sim.mvs.frames import apply

    wp = camera.workpiece
    origins_s = np.stack([np.full(ROWS, -camera.standoff_mm), camera._y_rows, np.zeros(ROWS)], axis=1)
    origins = apply(T_W_S, origins_s)
    d = np.asarray(T_W_S)[0:3, 0]
    out = np.full(ROWS, np.nan)
    if d[2] > -1e-9:
        return out
    t_up = (wp.step_mm - origins[:, 2]) / d[2]
    t_low = -origins[:, 2] / d[2]
    p_up = origins[:, 0:2] + t_up[:, None] * d[0:2]
    p_low = origins[:, 0:2] + t_low[:, None] * d[0:2]
    s_up, lat_up = wp.nearest_many(p_up)
    s_low, lat_low = wp.nearest_many(p_low)
    upper = (wp.heights_from(s_up, lat_up) == wp.step_mm) & (t_up > 0)
    lower = (wp.heights_from(s_low, lat_low) == 0.0) & (t_low > 0)
    side_up, side_low = wp.upper_sign * lat_up, wp.upper_sign * lat_low
    along = (s_low >= -wp.lead_in_mm) & (s_low <= wp.length_mm + wp.lead_out_mm)
    face = ~upper & (side_up < 0) & (side_low >= 0) & (side_low <= wp.width_mm) & along & (t_up > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        t_face = t_up + (-side_up) / (side_low - side_up) * (t_low - t_up)
    t = np.where(upper, t_up, np.where(face, t_face, np.where(lower, t_low, np.nan)))
    out[:] = t - camera.standoff_mm
    return out


CAMERAS = {name: MvsCamera(load_workpiece(name)) for name in ("step_input", "ramp_r500")}


@settings(max_examples=150, deadline=None)
@given(name=st.sampled_from(sorted(CAMERAS)), s=st.floats(-80.0, 1500.0), dx=st.floats(-40, 40),
       dy=st.floats(-40, 40), dz=st.floats(-30, 30), yaw=st.floats(-0.6, 0.6), tilt=st.floats(-0.6, 0.6),
       roll=st.floats(-0.5, 0.5))
def test_local_nearest_search_renders_the_reference_frames_bit_for_bit(name, s, dx, dy, dz, yaw, tilt, roll):
    """Only the segments near the frame are projected; the depths are the full search's, bit for bit,
    anywhere along both workpieces (ends, the 5 degree turn, the arc), off the seam and tilted."""
    from droid.sim.mvs.frames import rot_x, rot_z

    camera = CAMERAS[name]
    pose = seam_frame(camera.workpiece, min(s, camera.workpiece.length_mm + 60.0)) @ translation(dx, dy, dz) \
        @ rot_z(yaw) @ rot_y(tilt) @ rot_x(roll)
    assert camera.profile_mm(pose).tobytes() == reference_profile_mm(camera, pose).tobytes()


def test_a_frame_at_an_unchanged_pose_is_the_one_rendered_anew():
    """frame() renders the noise-free profile once per pose (the arms at rest): frame for frame the
    same columns and the same random numbers as a camera that renders every frame."""
    from droid.sim.mvs.devices import ToolSensorCore
    from droid.sim.mvs.tool_sensor import ToolNoise

    noise = CameraNoise(jitter_px=0.5, spurious_fraction=0.05, drop_probability=0.1)
    kept, fresh = MvsCamera(STEP, noise=noise), MvsCamera(STEP, noise=noise)
    a, b = seam_frame(STEP, 50.0), pose_for_reading(STEP, 80.0, 1.0, -2.0, 0.05)
    rng_k, rng_f = np.random.default_rng(3), np.random.default_rng(3)
    tool_k, tool_f = (ToolSensorCore(STEP, ToolNoise(0.01, 0.05, 0.001, 0.1), seed=4) for _ in range(2))
    for pose in (a, a, a.copy(), b, b, a, a):
        fresh._seen = None  # renders every frame
        got, want = kept.frame(pose, rng_k), fresh.frame(pose, rng_f)
        assert (got is None and want is None) or np.array_equal(got, want)
        tool_f._seen = None
        assert tool_k.step(pose) == tool_f.step(pose)
    assert rng_k.bit_generator.state == rng_f.bit_generator.state
