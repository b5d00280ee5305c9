"""Workpieces as data: bundled tracks, geometry queries, file validation."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from droid.cli import BadInput
from droid.sim.workpiece import bundled_workpieces, load_workpiece
from tests.refusals import refused

RAMPS = ["ramp_r200", "ramp_r300", "ramp_r400", "ramp_r500"]


def test_bundled_workpieces_are_the_thesis_tracks():
    assert set(bundled_workpieces()) >= {"step_input", *RAMPS}


def test_step_input_geometry():
    wp = load_workpiece("step_input")
    assert wp.length_mm == pytest.approx(700.0)
    xy, heading = wp.point_at(100.0 - 1e-9)
    assert xy == pytest.approx([100.0, 0.0]) and heading == pytest.approx(0.0)
    xy, heading = wp.point_at(700.0)
    five = math.radians(5.0)
    assert xy == pytest.approx([100 + 600 * math.cos(five), 600 * math.sin(five)])
    assert heading == pytest.approx(five)
    assert (wp.step_mm, wp.width_mm, wp.upper_side) == (2.0, 50.0, "left")


@pytest.mark.parametrize("name", RAMPS)
def test_ramp_geometry(name):
    wp = load_workpiece(name)
    radius = float(name.split("_r")[1])
    assert wp.length_mm == pytest.approx(600 + math.pi / 2 * radius)
    xy, heading = wp.point_at(wp.length_mm)
    assert xy == pytest.approx([300 + radius, radius + 300])
    assert heading == pytest.approx(math.pi / 2)
    # Mid-arc: 45 degrees round a circle centred at (300, R).
    xy, heading = wp.point_at(300 + math.pi / 4 * radius)
    assert xy == pytest.approx([300 + radius * math.sin(math.pi / 4), radius * (1 - math.cos(math.pi / 4))])
    assert heading == pytest.approx(math.pi / 4)


def _left(heading):
    return np.array([-math.sin(heading), math.cos(heading)])


@settings(max_examples=150, deadline=None)
@given(name=st.sampled_from(RAMPS), s=st.floats(0, 1), lateral=st.floats(-45, 45),
       z=st.floats(-5, 5))
def test_nearest_inverts_point_at_on_smooth_tracks(name, s, lateral, z):
    wp = load_workpiece(name)
    s_mm = s * wp.length_mm
    xy, heading = wp.point_at(s_mm)
    p = np.append(xy + lateral * _left(heading), z)
    s_got, lat_got, height = wp.nearest(p)
    assert s_got == pytest.approx(s_mm, abs=1e-6)
    assert lat_got == pytest.approx(lateral, abs=1e-6)
    assert height == z


@pytest.mark.parametrize("s_mm", [0.0, 50.0, 95.0, 105.0, 400.0, 700.0])
@pytest.mark.parametrize("lateral", [-30.0, -1.0, 1.0, 30.0])
def test_nearest_on_step_input_away_from_the_kink(s_mm, lateral):
    wp = load_workpiece("step_input")
    xy, heading = wp.point_at(s_mm)
    s_got, lat_got, _ = wp.nearest(np.append(xy + lateral * _left(heading), 0.0))
    assert (s_got, lat_got) == pytest.approx((s_mm, lateral), abs=1e-6)


def test_nearest_extends_the_seam_beyond_its_ends():
    wp = load_workpiece("ramp_r300")
    assert wp.nearest([-20.0, 3.0, 1.0]) == pytest.approx((-20.0, 3.0, 1.0))
    end, heading = wp.point_at(wp.length_mm)
    p = end + 15.0 * np.array([math.cos(heading), math.sin(heading)]) - 4.0 * _left(heading)
    assert wp.nearest(np.append(p, 0.0)) == pytest.approx((wp.length_mm + 15.0, -4.0, 0.0))


def test_surface_heights_lap_joint():
    wp = load_workpiece("step_input")  # upper surface on the left (+y at the start)
    assert wp.surface_height([50.0, 10.0]) == 2.0
    assert wp.surface_height([50.0, -10.0]) == 0.0
    assert wp.surface_height([50.0, 49.9]) == 2.0
    assert wp.surface_height([50.0, 50.1]) is None
    assert wp.surface_height([50.0, -50.1]) is None
    assert wp.surface_height([-5.0, -3.0]) == 0.0  # within the 10 mm lead-in
    assert wp.surface_height([-10.5, -3.0]) is None
    heights = wp.surface_heights(np.array([[50.0, 10.0], [50.0, -10.0], [50.0, 80.0]]))
    assert heights[:2] == pytest.approx([2.0, 0.0]) and np.isnan(heights[2])


def test_right_side_upper_and_custom_start(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text(
        'step_mm = 3.0\nwidth_mm = 20.0\nupper_side = "right"\n'
        "[start]\nx_mm = 10.0\ny_mm = 5.0\nheading_deg = 90.0\n"
        '[[segment]]\ntype = "arc"\nradius_mm = 100.0\nangle_deg = -90.0\n'
    )
    wp = load_workpiece(str(path))
    assert wp.name == "mine"
    assert wp.length_mm == pytest.approx(50 * math.pi)
    xy, heading = wp.point_at(wp.length_mm)  # right turn from heading +y round (110, 5)
    assert xy == pytest.approx([110.0, 105.0]) and heading == pytest.approx(0.0)
    xy, heading = wp.point_at(20.0)
    right = -_left(heading)
    assert wp.surface_height(xy + 5.0 * right) == 3.0
    assert wp.surface_height(xy - 5.0 * right) == 0.0


BAD_FILES = [
    ("", "at least one [[segment]]"),
    ('[[segment]]\ntype = "turn"\nangle_deg = 5.0\n', "at least one line or arc"),
    ('[[segment]]\ntype = "lin"\nlength_mm = 5.0\n', "segment 1: type must be one of"),
    ('[[segment]]\ntype = "line"\nlenght_mm = 5.0\n', "segment 1: unknown key 'lenght_mm'"),
    ('[[segment]]\ntype = "line"\n', "segment 1: missing length_mm"),
    ('[[segment]]\ntype = "line"\nlength_mm = -5.0\n', "length_mm must be > 0"),
    ('[[segment]]\ntype = "line"\nlength_mm = "5"\n', "length_mm must be a finite number"),
    ('[[segment]]\ntype = "line"\nlength_mm = nan\n', "segment[0].length_mm = nan: must be a finite number"),
    ('width_mm = 0\n[[segment]]\ntype = "line"\nlength_mm = 5.0\n', "width_mm must be > 0"),
    ('upper_side = "up"\n[[segment]]\ntype = "line"\nlength_mm = 5.0\n', "upper_side must be"),
    ('colour = "red"\n[[segment]]\ntype = "line"\nlength_mm = 5.0\n', "unknown key 'colour'"),
    ('[[segment]]\ntype = "arc"\nradius_mm = 40.0\nangle_deg = 90.0\n', "radius_mm (40) must exceed width_mm (50)"),
    ('[[segment]]\ntype = "arc"\nradius_mm = 400.0\nangle_deg = 0\n', "angle_deg must be non-zero"),
    ('[[segment]]\ntype = "line"\nlength_mm = 5.0\n[[segment]]\ntype = "turn"\nangle_deg = 180\n',
     "segment 2: angle_deg must be within (-180, 180)"),
    ("[start]\nz_mm = 1\n[[segment]]\ntype = \"line\"\nlength_mm = 5.0\n", "[start]: unknown key 'z_mm'"),
    ("this is = not toml [", "not valid TOML"),
]


@pytest.mark.parametrize("text,message", BAD_FILES)
def test_bad_workpiece_files_give_one_line_errors(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    msg = refused(path, text, lambda p: load_workpiece(str(p)))
    assert message in msg and str(path) in msg


def test_unknown_workpiece_names_the_bundled_ones():
    with pytest.raises(BadInput, match="unknown workpiece 'nope'.*step_input"):
        load_workpiece("nope")
    with pytest.raises(BadInput, match="not found"):
        load_workpiece("/no/such/file.toml")
