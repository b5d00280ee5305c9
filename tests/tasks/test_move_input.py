"""droid-move / droid-home: bad input exits 2 with one line, before any database is touched."""
from __future__ import annotations

import pytest

from droid.brain.db.shmdb import cell_objects
from tests.brain.cellutil import droid, make_cell_file


@pytest.fixture
def cellfile(tmp_path, cell_name):
    return make_cell_file(tmp_path, cell_name)


BAD_MOVES = [
    (["arm1", "joint", "0", "0", "0", "0", "0", "nan", "1"], "not a finite number"),
    (["arm1", "joint", "0", "0", "0", "0", "0", "inf", "1"], "not a finite number"),
    (["arm1", "joint", "0", "0", "0", "1"], "needs 6 target values"),
    (["arm1", "joint", "0", "0", "0", "0", "0", "0", "0", "1"], "needs 6 target values"),
    (["arm1", "joint", "0", "0", "0", "0", "0", "0", "0"], "SECONDS must be > 0"),
    (["arm1", "joint", "0", "0", "0", "0", "0", "0", "-2"], "SECONDS must be > 0"),
    (["arm1", "joint", "0", "0", "0", "0", "0", "0x10", "1"], "not a number"),
    (["arm1", "joint", "0", "0", "0", "0", "0", "0.5", "1"], "whole numbers"),
    (["arm1", "joint", "0", "0", "0", "0", "0", "99999999", "1"], "outside"),
    (["arm1", "joint", "0", "0", "0", "0", "0", "0", "0.001"], "shorter than one heartbeat tick"),
    (["arm1", "cart", "3000", "0", "1340", "0", "90", "0", "2"], "unreachable"),
    (["arm1", "cart", "300", "100", "1340", "0", "90", "nan", "2"], "not a finite number"),
    (["arm1", "spin", "0", "0", "0", "0", "0", "0", "1"], "invalid choice"),
    (["arm9", "joint", "0", "0", "0", "0", "0", "0", "1"], "unknown subunit"),
    (["mvs", "joint", "0", "0", "0", "0", "0", "0", "1"], "not an arm"),
    (["arm1"], "required"),
]


@pytest.mark.parametrize("args,msg", BAD_MOVES, ids=[" ".join(a) for a, _ in BAD_MOVES])
def test_bad_move_exits_2_without_touching_the_cell(args, msg, cellfile, cell_name):
    out = droid("droid.tasks.move", *args, "--cell", str(cellfile))
    assert out.returncode == 2, out.stderr
    assert msg in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert cell_objects(cell_name) == []  # nothing was created or attached


def test_move_when_cell_is_down_is_a_runtime_failure(cellfile):
    out = droid("droid.tasks.move", "arm1", "joint", "0", "0", "0", "0", "0", "0", "1", "--cell", str(cellfile))
    assert out.returncode == 1 and "is the cell up" in out.stderr


@pytest.mark.parametrize("args,msg", [
    (["arm9"], "unknown subunit"),
    (["mvs"], "not an arm"),
    (["arm1", "--timeout", "-1"], "must be > 0"),
    ([], "required"),
])
def test_bad_home(args, msg, cellfile):
    out = droid("droid.tasks.home", *args, "--cell", str(cellfile))
    assert out.returncode == 2 and msg in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_jog_trapezoid_steps_sum_exactly_and_respect_limits():
    from hypothesis import given, settings, strategies as st

    from droid.tasks.jog import trapezoid_steps

    @settings(deadline=None, max_examples=60)
    @given(st.integers(-200000, 200000), st.floats(2000, 1e5), st.floats(1000, 1e6))
    def check(distance, vmax, accel):
        dt = 1 / 60
        steps = trapezoid_steps(distance, vmax, accel, dt)
        assert sum(steps) == distance
        assert all(abs(s) <= max(1, vmax * dt) for s in steps)
        assert all((s > 0) == (distance > 0) for s in steps)
        speeds = [0] + [abs(s) / dt for s in steps]
        assert all(b - a <= accel * dt + 1 / dt for a, b in zip(speeds, speeds[1:]))

    check()
