"""Workpieces beyond the plane (issue 15): rise, curves, roll and step profiles, gaps, tacks --
their geometry, what the camera twin, the tool-tip and the ideal sensors see, and validation."""
from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from droid.cli import BadInput
from droid.sim.mvs.trial_sensors import LeadSensor
from droid.sim.mvs.camera import CameraNoise, MvsCamera
from droid.sim.seam3d import TACK_WIDTH_MM
from droid.sim.mvs.tool_sensor import measure, pose_for_reading
from droid.sim.workpiece import WORKPIECE_DIR, Workpiece, bundled_workpieces, load_workpiece
from droid.subunits.mvs.sensor import SensorCore
from tests.refusals import refused

NEW = ["helix_r300", "cad_curve", "gaps_tacks"]
PLANE = ["step_input", "ramp_r200", "ramp_r300", "ramp_r400", "ramp_r500"]


def wp_from(tmp_path, text, name="w.toml"):
    path = tmp_path / name
    path.write_text(text)
    return load_workpiece(str(path))


def test_the_examples_ship_and_the_thesis_tracks_keep_their_plane_model():
    assert set(NEW) <= set(bundled_workpieces())
    for name in PLANE:
        assert load_workpiece(name).planar
    for name in NEW:
        wp = load_workpiece(name)
        assert not wp.planar and wp.length_mm > 500


@pytest.mark.parametrize("name", PLANE)
def test_the_3d_renderer_matches_the_exact_plane_model(name):
    """The sampled 3-D seam of a plane workpiece gives the plane model's stripe and readings."""
    wp = load_workpiece(name)
    cam = MvsCamera(wp)
    rng = np.random.default_rng(3)
    compared = 0
    for _ in range(60):
        s = rng.uniform(0, wp.length_mm)
        if name == "step_input" and abs(s - 100) < 40:  # the instantaneous turn: the models differ there
            continue
        T = pose_for_reading(wp, s, rng.uniform(-8, 8), rng.uniform(-12, 12), rng.uniform(-0.4, 0.4))
        ref = cam.profile_mm(T)
        got = wp.seam.stripe_depth_mm(T, cam._y_rows, cam.standoff_mm)
        assert np.array_equal(np.isfinite(ref), np.isfinite(got))
        assert np.nanmax(np.abs(ref - got)) < 0.005  # mm: 1/20 of a column
        a, b = measure(T, wp), wp.seam.measure(T)
        assert abs(a.lateral_mm - b.lateral_mm) < 1e-3 and abs(a.height_mm - b.height_mm) < 1e-3
        assert abs(a.roll_rad - b.roll_rad) < 1e-6 and abs(a.s_mm - b.s_mm) < 1e-2
        compared += 1
    assert compared > 40


def test_a_helix_climbs_its_rise_along_its_arc_length(tmp_path):
    wp = wp_from(tmp_path, '[[segment]]\ntype = "arc"\nradius_mm = 200\nangle_deg = 180\nrise_mm = 50\n'
                           '[[segment]]\ntype = "line"\nlength_mm = 100\nrise_mm = -30\n')
    arc = math.hypot(200 * math.pi, 50)
    assert wp.length_mm == pytest.approx(arc + math.hypot(100, 30), abs=1e-6)
    p, t, n, l = wp.seam.point_frame(arc)
    assert p == pytest.approx([0.0, 400.0, 50.0], abs=1e-6)  # half a turn left, 50 mm up
    assert t @ n == pytest.approx(0, abs=1e-9) and l @ n == pytest.approx(0, abs=1e-9)
    assert t[2] == pytest.approx(-30 / math.hypot(100, 30))  # at the junction: the line's (later) side
    end, _, _, _ = wp.seam.point_frame(wp.length_mm)
    assert end == pytest.approx([-100.0, 400.0, 20.0], abs=1e-6)  # heading -x after the half turn
    quarter, tq, _, _ = wp.seam.point_frame(arc / 2)
    assert quarter == pytest.approx([200.0, 200.0, 25.0], abs=1e-3)
    assert tq == pytest.approx([0.0, math.cos(math.atan2(50, 200 * math.pi)), 50 / arc], abs=1e-6)  # climbing


@pytest.mark.parametrize("name", NEW)
def test_tool_sensor_and_ideal_sensor_read_back_the_pose_offsets(name):
    """pose_for_reading puts a frame where it reads (x, y, roll): measure returns them anywhere
    on the seam -- climbing, curving, rolled."""
    wp = load_workpiece(name)
    lead = LeadSensor(wp, "ideal", seed=1)
    rng = np.random.default_rng(7)
    for _ in range(40):
        s = rng.uniform(5, wp.length_mm - 5)
        x, y, roll = rng.uniform(-5, 5), rng.uniform(-10, 10), rng.uniform(-0.3, 0.3)
        T = pose_for_reading(wp, s, x, y, roll)
        m = measure(T, wp)
        assert (m.height_mm, m.lateral_mm, m.roll_rad, m.s_mm) == pytest.approx((x, y, roll, s), abs=1e-6)
        r = lead.read(T)
        if wp.in_gap(s):
            assert not r.valid
        else:
            assert r.valid and abs(r.y_mm - y) < 0.5 and abs(r.x_mm - x) < 0.2


@pytest.mark.parametrize("name", ["helix_r300", "cad_curve"])
def test_the_camera_twin_renders_3d_seams_the_feature_code_finds(name):
    wp = load_workpiece(name)
    cam = MvsCamera(wp, noise=CameraNoise())
    core = SensorCore(cam.calib)
    rng = np.random.default_rng(11)
    for _ in range(30):
        s = rng.uniform(10, wp.length_mm - 10)
        x, y, roll = rng.uniform(-4, 4), rng.uniform(-6, 6), rng.uniform(-0.25, 0.25)
        f = core.process(cam.frame(pose_for_reading(wp, s, x, y, roll), rng))
        assert f is not None, s
        assert abs(f.x_mm - x) < 0.15 and abs(f.y_mm - y) < 0.4 and abs(f.roll_rad - roll) < 0.02


def test_roll_profile_turns_the_surfaces_about_the_seam(tmp_path):
    wp = wp_from(tmp_path, 'roll_profile = [[100, 0], [200, 30]]\n[[segment]]\ntype = "line"\nlength_mm = 300\n')
    for s, deg in ((50, 0), (100, 0), (150, 15), (200, 30), (280, 30)):
        _, t, n, l = wp.seam.point_frame(s)
        assert math.degrees(math.atan2(l[2], n[2])) == pytest.approx(deg, abs=1e-6)  # + lifts the left side
        # a sensor held level (no roll) reads the surface's roll
        level = pose_for_reading(wp, s, 0, 0, 0)
        level[0:3, 0:3] = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]]).T @ np.eye(3) if False else level[0:3, 0:3]
    cam = MvsCamera(wp, noise=CameraNoise())
    flat = np.eye(4)
    flat[0:3, 0], flat[0:3, 1], flat[0:3, 2] = (0, 0, -1), (0, 1, 0), (1, 0, 0)
    for s, deg in ((50, 0.0), (250, 30.0)):  # a sensor held level reads the surface's roll
        T = flat.copy()
        T[0:3, 3] = (s, 0, 20.0)
        m = measure(T, wp)
        assert math.degrees(m.roll_rad) == pytest.approx(deg, abs=1e-6)  # as the lead sensor reports roll
        f = SensorCore(cam.calib).process(cam.frame(T, np.random.default_rng(0)))
        assert f is not None and math.degrees(f.roll_rad) == pytest.approx(deg, abs=0.5)


def test_step_profile_gaps_and_tacks_as_the_camera_sees_them():
    wp = load_workpiece("gaps_tacks")
    cam = MvsCamera(wp, noise=CameraNoise())
    rows = cam._y_rows

    def step_seen(s):
        d = cam.profile_mm(pose_for_reading(wp, s, 0, 0, 0))
        lower = d[(rows < -2)]
        upper = d[(rows > TACK_WIDTH_MM + 1)]
        bump = d[(rows > 0.3) & (rows < TACK_WIDTH_MM - 0.3)]
        return float(np.median(lower - 0) - np.median(upper)), float(np.median(lower) - np.median(bump))

    assert step_seen(50) == pytest.approx((2.0, 2.0), abs=1e-6)
    assert step_seen(300) == pytest.approx((2.5, 2.5), abs=1e-6)  # the profile: 2 -> 3 mm over 100..500
    assert step_seen(550) == pytest.approx((3.0, 3.0), abs=1e-6)
    assert step_seen(255) == pytest.approx((0.0, 0.0), abs=1e-6)  # in the gap: flat, no feature
    assert step_seen(183) == pytest.approx((2.0 + 83 / 400, 3.0 + 83 / 400), abs=1e-6)  # a tack: +1 mm bump
    core = SensorCore(cam.calib)
    assert core.process(cam.frame(pose_for_reading(wp, 255, 0, 0, 0), np.random.default_rng(0))) is None
    m = measure(pose_for_reading(wp, 255, 1.0, 2.0, 0.0), wp)  # the tool-tip sensor still measures
    assert (m.height_mm, m.lateral_mm) == pytest.approx((1.0, 2.0), abs=1e-9)


def test_curve_from_csv_equals_inline_points_and_linear_passes_the_points(tmp_path):
    pts = [[0, 0, 0], [40, 5, 0], [80, 20, 3], [120, 20, 6], [160, 10, 6]]
    (tmp_path / "c.csv").write_text("x_mm,y_mm,z_mm\n" + "\n".join(",".join(map(str, p)) for p in pts) + "\n")
    head = '[[segment]]\ntype = "line"\nlength_mm = 50\n[[segment]]\ntype = "curve"\n'
    a = wp_from(tmp_path, head + 'csv = "c.csv"\n', "a.toml")
    b = wp_from(tmp_path, head + f"points_mm = {pts}\n", "b.toml")
    assert np.array_equal(a.seam.p, b.seam.p) and a.length_mm == b.length_mm
    lin = wp_from(tmp_path, head + f'points_mm = {pts}\ninterpolation = "linear"\n', "c.toml")
    chord = sum(math.dist(p, q) for p, q in zip(pts, pts[1:]))
    assert lin.length_mm == pytest.approx(50 + chord)
    assert b.length_mm > lin.length_mm  # the spline bends between the points
    for curve in (lin, b):  # both pass through every point (the curve starts at the line's end)
        for p in pts:
            target = np.array([50.0 + p[0], p[1], p[2]])
            assert np.min(np.linalg.norm(curve.seam.p - target, axis=1)) < 1e-6


@pytest.mark.parametrize("text, message", [
    ('[[segment]]\ntype = "curve"\n', "segment 1: give points_mm or csv"),
    ('[[segment]]\ntype = "curve"\npoints_mm = [[1, 0, 0], [5, 0, 0]]\n', "segment 1: points_mm: the first point"),
    ('[[segment]]\ntype = "curve"\npoints_mm = [[0, 0, 0]]\n', "segment 1: points_mm: needs at least 2"),
    ('[[segment]]\ntype = "curve"\npoints_mm = [[0, 0, 0], [5, 0]]\n', "segment 1: points_mm: point 2"),
    ('[[segment]]\ntype = "curve"\npoints_mm = [[0, 0, 0], [0, 0, 0]]\n', "segment 1: points_mm: points 1 and 2"),
    ('[[segment]]\ntype = "curve"\npoints_mm = [[0, 0, 0], [0, 0, 5]]\n', "segment 1: points_mm: the curve runs"),
    ('[[segment]]\ntype = "curve"\ncsv = "nope.csv"\n', "segment 1: csv file not found"),
    ('[[segment]]\ntype = "curve"\npoints_mm = [[0, 0, 0], [5, 0, 0]]\ninterpolation = "cubic"\n',
     "segment 1: interpolation must be"),
    ('[[segment]]\ntype = "line"\nlength_mm = 5\nrise_mm = "up"\n', "segment 1: rise_mm must be a finite number"),
    ('[[segment]]\ntype = "turn"\nangle_deg = 5\nrise_mm = 1\n', "segment 1: unknown key 'rise_mm'"),
    ('roll_profile = [[10, 0], [5, 10]]\n[[segment]]\ntype = "line"\nlength_mm = 50\n',
     "roll_profile: point 2: s_mm must increase"),
    ('roll_profile = [[10, 95]]\n[[segment]]\ntype = "line"\nlength_mm = 50\n', "roll_profile: point 1: roll_deg"),
    ('step_profile = [[10, 0]]\n[[segment]]\ntype = "line"\nlength_mm = 50\n', "step_profile: point 1: step_mm"),
    ('step_profile = 2\n[[segment]]\ntype = "line"\nlength_mm = 50\n', "step_profile must be a non-empty list"),
    ('[[segment]]\ntype = "line"\nlength_mm = 50\n[[gap]]\ns_mm = 10\nwidth_mm = 3\n', "[[gap]] 1: unknown key"),
    ('[[segment]]\ntype = "line"\nlength_mm = 50\n[[gap]]\ns_mm = 45\nlength_mm = 10\n', "[[gap]] 1: s_mm + length_mm"),
    ('[[segment]]\ntype = "line"\nlength_mm = 50\n[[tack]]\ns_mm = 5\nlength_mm = 3\nheight_mm = 0\n',
     "[[tack]] 1: height_mm must be > 0"),
    ('[[segment]]\ntype = "line"\nlength_mm = 50\n[[tack]]\ns_mm = 5\nlength_mm = 3\n', "[[tack]] 1: missing height_mm"),
])
def test_bad_3d_workpieces_give_one_line_errors_naming_file_segment_and_key(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    msg = refused(path, text, lambda p: load_workpiece(str(p)))
    assert str(path) in msg and message in msg, msg


def test_a_bad_csv_names_the_file_and_line(tmp_path):
    (tmp_path / "c.csv").write_text("x_mm,y_mm,z_mm\n0,0,0\n1,2\n")
    path = tmp_path / "w.toml"
    path.write_text('[[segment]]\ntype = "curve"\ncsv = "c.csv"\n')
    with pytest.raises(BadInput, match=r"segment 1: csv .*c\.csv: line 3: expected three finite numbers"):
        load_workpiece(str(path))
    (tmp_path / "c.csv").write_text("x,y,z\n0,0,0\n")
    with pytest.raises(BadInput, match=r"the header must be x_mm,y_mm,z_mm"):
        load_workpiece(str(path))


def test_a_bad_workpiece_in_a_plan_exits_2_naming_plan_key_and_file(tmp_path):
    (tmp_path / "bad.toml").write_text('[[segment]]\ntype = "curve"\npoints_mm = [[0, 0, 0]]\n')
    (tmp_path / "p.toml").write_text('name = "x"\n[sweep]\nworkpiece = ["bad.toml"]\n')
    p = subprocess.run([sys.executable, "-m", "droid.experiments.cli", "run", "--plan", str(tmp_path / "p.toml"),
                        "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2
    err = p.stderr.strip()
    assert len(err.splitlines()) == 1 and "p.toml" in err and "workpiece" in err and "segment 1" in err, err


@pytest.mark.parametrize("name", NEW)
def test_a_trial_runs_on_every_example_with_the_layouts_default_mount(name):
    from droid.experiments.trial import TrialConfig, run_trial

    r = run_trial(TrialConfig(trial_id="x", position="i", workpiece=name, speed_mm_s=32, length_mm=260, arm="fast",
                              sensor="ideal"))
    assert r.stop_reason in ("end of seam", "seam lost")
    s = r.column("s_mm")
    assert np.nanmax(s) > 200
    lat = r.column("tool_lateral_mm")
    assert np.isfinite(lat).sum() > 50


def test_workpiece_constructed_in_code_keeps_working():
    from droid.sim.workpiece import Segment

    wp = Workpiece("w", (Segment(0.0, 100.0, (0.0, 0.0), 0.0),))
    assert wp.planar and wp.seam.length_mm == 100.0
    assert wp.seam_frame(50.0)[0:3, 3] == pytest.approx([50.0, 0.0, 0.0])
    assert (WORKPIECE_DIR / "cad_curve.csv").is_file()


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=40, deadline=None)
@given(radius=st.floats(60, 800), angle=st.floats(-300, 300).filter(lambda a: abs(a) > 5),
       rise=st.floats(-80, 80), line_rise=st.floats(-40, 40), roll=st.floats(-60, 60),
       frac=st.floats(0.02, 0.98), x=st.floats(-5, 5), y=st.floats(-10, 10), r=st.floats(-0.4, 0.4))
def test_any_helix_reads_back_its_pose_offsets(tmp_path_factory, radius, angle, rise, line_rise, roll, frac,
                                               x, y, r):
    text = (f"roll_profile = [[0, 0], [400, {roll}]]\n"
            f'[[segment]]\ntype = "line"\nlength_mm = 80\nrise_mm = {line_rise}\n'
            f'[[segment]]\ntype = "arc"\nradius_mm = {radius}\nangle_deg = {angle}\nrise_mm = {rise}\n')
    wp = wp_from(tmp_path_factory.mktemp("h"), text)
    s = frac * wp.length_mm
    T = pose_for_reading(wp, s, x, y, r)
    R = T[0:3, 0:3]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-9) and np.linalg.det(R) == pytest.approx(1.0)
    m = measure(T, wp)
    assert m is not None
    assert (m.height_mm, m.lateral_mm, m.roll_rad) == pytest.approx((x, y, r), abs=1e-6)
    assert m.s_mm == pytest.approx(s, abs=1e-6)
