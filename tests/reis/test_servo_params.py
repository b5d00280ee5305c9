"""ServoParams validation, robot-file loading, and the coupled zero solution (§4.1.1.3, §4.1.5.3)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from droid.subunits.reis.homing import zero_from_edges
from droid.subunits.reis.robot_file import load_gearing, robot_file_path
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.servo_params import Mode, ServoParams


def test_defaults_come_from_the_robot_file():
    p = ServoParams()
    m = load_gearing(robot_file_path()).joint_to_counts_matrix
    assert np.allclose(p.joint_to_counts, m)
    q = ServoParams.for_robot_file(robot_file_path(), kp_dac_per_count=(1.0,) * 6)
    assert q.home_search_dir == tuple(int(np.sign(d)) for d in np.diag(m))
    assert q.kp_dac_per_count == (1.0,) * 6


@pytest.mark.parametrize(
    "change",
    [
        dict(home_order=(0, 1, 2, 3, 4, 4)),
        dict(queue_steps=0),
        dict(command_rate_hz=600.0),
        dict(starve_grace_ticks=8),
        dict(home_search_dir=(1, 1, 1, 1, 1, 0)),
        dict(target_min_counts=(0,) * 6, target_max_counts=(0,) * 6),
        dict(joint_to_counts=((0.0,) * 6,) * 6),
    ],
)
def test_bad_params_are_rejected(change):
    with pytest.raises(ValueError):
        replace(ServoParams(), **change)


@given(
    st.lists(st.floats(-90, 90), min_size=6, max_size=6),
    st.lists(st.integers(-10**6, 10**6), min_size=6, max_size=6),
    st.lists(st.lists(st.floats(-120, 120), min_size=6, max_size=6), min_size=6, max_size=6),
)
def test_zero_from_edges_inverts_the_coupled_gearing(switch_deg, zero, other_joints_deg):
    """Each snapshot E_i has joint i on its switch and the other joints anywhere."""
    m = np.asarray(ServoParams().joint_to_counts)
    zero = np.asarray(zero, float)
    edges = []
    for i in range(6):
        q = np.asarray(other_joints_deg[i])
        q[i] = switch_deg[i]
        edges.append(m @ q + zero)
    z = zero_from_edges(np.array(edges), switch_deg, m)
    assert np.all(np.abs(z - zero) <= 0.5 + 1e-6)


def test_servo_rejects_commands_before_its_first_reading_and_bad_shapes():
    core = ServoCore()
    assert not core.command(Mode.JOG, (1,) * 6)
    assert not core.command(Mode.HOME)
    core.step((0,) * 6, (False,) * 6)
    with pytest.raises(ValueError):
        core.command(Mode.JOG, (1,) * 5)
    with pytest.raises(ValueError):
        core.step((0,) * 5, (False,) * 6)
    assert core.command(Mode.HOME)  # the earlier rejected HOME did not count as "already HOME"
    assert core.homing


def test_the_at_rest_edge_probe_parameters_are_checked():
    """Homing's step 5 (the switch edge bracketed at rest): a negative resolution or a zero
    settle is refused; resolution 0 switches the step off."""
    import pytest as _pytest

    from droid.subunits.reis.servo_params import ServoParams as _SP

    assert _SP(home_probe_resolution_counts=0).home_probe_resolution_counts == 0
    for bad in ({"home_probe_resolution_counts": -1}, {"home_probe_settle_ticks": 0}, {"home_probe_counts": 0},
                {"home_probe_max": 0}):
        with _pytest.raises(ValueError, match="home_probe"):
            _SP(**bad)
