"""Robot models as data files: loading, validation, adding a robot by a file only."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from droid.kinematics import RobotFileError, list_robots, load_robot
from droid.kinematics.robots import BUNDLED_DIR
from helpers_kin import offset_robot_toml


def test_bundled_robots():
    assert {"reis_v15", "fanuc_s400"} <= set(list_robots())
    reis = load_robot("reis_v15")
    assert reis.name == "reis_v15" and reis.assumed is False
    fanuc = load_robot("fanuc_s400")
    assert fanuc.name == "fanuc_s400" and fanuc.assumed is True
    assert load_robot("reis_v15") is reis  # bundled models are cached (immutable)


def test_reis_data_matches_the_thesis(reis):
    p = reis.opw
    assert (p.c1, p.c2, p.c3) == (725.0, 600.0, 540.0)
    assert (p.a1, p.a2, p.b, p.c4) == (0.0, 0.0, 0.0, 0.0)
    assert p.offsets_deg == (0.0, 0.0, -90.0, -180.0, 0.0, 0.0)
    assert p.signs == (1, -1, -1, 1, 1, 1)
    assert reis.dh.d_mm == (725.0, 0.0, 0.0, 540.0, 0.0, 0.0)
    assert reis.dh.a_mm == (0.0, 600.0, 0.0, 0.0, 0.0, 0.0)
    assert reis.dh.alpha_deg == (90.0, 0.0, 90.0, -90.0, 90.0, 0.0)
    assert reis.dh.theta_offset_deg == (0.0, 90.0, 0.0, 0.0, 0.0, 0.0)
    # planner weights favour wrist motion (thesis §4.1.7)
    assert np.all(reis.weights[:3] > reis.weights[3:])


@pytest.mark.parametrize("name", ["reis_v15", "fanuc_s400"])
def test_model_attributes(name):
    m = load_robot(name)
    for attr in ("joint_min_deg", "joint_max_deg", "counts_min", "counts_max", "home_switch_deg", "vmax_deg_s", "weights"):
        assert getattr(m, attr).shape == (6,), attr
    assert m.base.shape == (4, 4) and np.array_equal(m.base, np.eye(4))
    assert np.all(m.joint_min_deg < m.joint_max_deg)
    assert np.all((m.home_switch_deg >= m.joint_min_deg) & (m.home_switch_deg <= m.joint_max_deg))
    assert np.all(m.vmax_deg_s > 0)
    assert m.counts_min.dtype == np.int64
    # the encoder limits contain the image of the joint-limit box (so the fast path may skip them)
    corners = np.array(np.meshgrid(*zip(m.joint_min_deg, m.joint_max_deg))).reshape(6, -1).T
    counts = m.gearing.joints_to_counts(corners)
    assert np.all(counts >= m.counts_min) and np.all(counts <= m.counts_max)
    assert m._counts_implied
    with pytest.raises(ValueError):
        m.weights[0] = 0.0  # read-only


def test_load_by_path(tmp_path):
    path = tmp_path / "copy.toml"
    path.write_text((BUNDLED_DIR / "reis_v15.toml").read_text())
    m = load_robot(str(path))
    assert m.name == "reis_v15" and m.source == str(path)
    assert np.allclose(m.fk([1, 2, 3, 4, 5, 6]), load_robot("reis_v15").fk([1, 2, 3, 4, 5, 6]))


def test_adding_a_robot_is_a_data_file(offset_robot):
    """A new OPW-class arm with every offset non-zero, from a file only: FK matches its D-H table, IK round trips."""
    assert offset_robot.opw.a1 == 150.0 and offset_robot.opw.b == 80.0 and offset_robot.opw.c4 == 100.0
    rng = np.random.default_rng(3)
    for q in rng.uniform(offset_robot.joint_min_deg, offset_robot.joint_max_deg, (100, 6)):
        t = offset_robot.fk(q)
        assert np.allclose(t, offset_robot.fk_dh(q), atol=1e-9)
        got = offset_robot.ik(t, q)
        assert np.allclose(offset_robot.fk(got), t, atol=1e-7)
    # coupling of the gearing from the file (a triangular wrist coupling) round trips too
    g = offset_robot.gearing
    assert np.allclose(g.counts_to_joints(g.joints_to_counts(q)), q, atol=1e-9)


def test_unknown_robot_name():
    with pytest.raises(RobotFileError, match="unknown robot 'nope'"):
        load_robot("nope")
    with pytest.raises(ValueError):
        load_robot("../etc/passwd")
    with pytest.raises(RobotFileError, match="not found"):
        load_robot("/nonexistent/robot.toml")


def _edit(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new, 1)


# Each row spoils the robot file its own way: ``old`` replaced by ``new``.
@pytest.mark.parametrize(
    "old, new, message",
    [
        (None, "\n[extra]\nx = 1\n", "unknown key"),  # None: appended to the file
        ("c2_mm = 700.0", "c2_mmm = 700.0", "unknown key"),
        ("[planner]\nweights = [3, 3, 3, 1, 1, 1]", "", "missing table [planner]"),
        ("weights = [3, 3, 3, 1, 1, 1]", "weights = [3, 3, 3, 1, 1]", "6 numbers"),
        ("weights = [3, 3, 3, 1, 1, 1]", "weights = [3, 3, 3, 1, 1, -1]", "weights"),
        ("c3_mm = 800.0", "c3_mm = 810.0", "[dh] and [opw] disagree"),
        ("signs = [1, -1, -1, 1, 1, 1]", "signs = [1, 1, -1, 1, 1, 1]", "disagree"),
        ("signs = [1, -1, -1, 1, 1, 1]", "signs = [1, 2, -1, 1, 1, 1]", "signs"),
        ("joint_max_deg = [170,", "joint_max_deg = [-175,", "joint_min_deg must be <"),
        ("switch_deg = [0, 0, 0, 0, 0, 0]", "switch_deg = [175, 0, 0, 0, 0, 0]", "home switch"),
        ("vmax_deg_s = [150,", "vmax_deg_s = [0,", "vmax_deg_s[0] = 0: is outside (0, "),
        ("c1_mm = 650.0", 'c1_mm = "650"', "finite number"),
        ("c1_mm = 650.0", "c1_mm = nan", "finite number"),
        ("[gearing]", "[gearing", "not valid TOML"),
        ("encoder_bits = 16", "encoder_bits = 16\nfoo = 1", "unknown key"),
        ("vmax_deg_s = [150", "counts_min = [0, 0, 0, 0, 0, 0]\nvmax_deg_s = [150", "both counts_min"),
    ],
)
def test_bad_robot_files_are_rejected_with_a_reason(tmp_path, old, new, message):
    text = offset_robot_toml("bad")
    path = tmp_path / "bad.toml"
    path.write_text(text + new if old is None else _edit(text, old, new))
    with pytest.raises(RobotFileError) as info:
        load_robot(str(path))
    assert message in str(info.value)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_kinematics_imports_nothing_else_of_droid():
    code = (
        "import sys, droid.kinematics, droid.kinematics.transforms, droid.kinematics.opw;"
        "print(sorted(m for m in sys.modules if m.startswith('droid')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    mods = eval(out)  # a printed list of module names
    # droid.numbers: the range check of every number read from a file (issue 16), a leaf
    # module that imports nothing of droid -- the flow stays one way
    assert mods and all(m in ("droid", "droid.numbers") or m.startswith("droid.kinematics") for m in mods), mods
