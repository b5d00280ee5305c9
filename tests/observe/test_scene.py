"""The scene: quaternions, link frames from the forward kinematics, the seam map."""
from __future__ import annotations

import numpy as np

from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T, zyz_to_R
from droid.observe.scene import SceneBuilder, quat


def R_of(q):
    x, y, z, w = q["x"], q["y"], q["z"], q["w"]
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_quaternion_of_rotations():
    rng = np.random.default_rng(3)
    cases = [np.eye(3), zyz_to_R(180, 0, 0), zyz_to_R(0, 180, 0), zyz_to_R(90, 180, 0), zyz_to_R(0, 90, 180)]
    cases += [zyz_to_R(*rng.uniform(-180, 180, 3)) for _ in range(200)]
    for R in cases:
        assert np.allclose(R_of(quat(R)), R, atol=1e-9)


def test_link_frames_end_at_the_wrist_centre():
    """The last D-H frame is the wrist centre of the robot's own FK, on the cell's base."""
    rng = np.random.default_rng(5)
    subs = [{"name": "arm1", "class": "arm6r", "robot": "reis_v15", "base": [0.0] * 6},
            {"name": "gmf1", "class": "arm6r", "robot": "fanuc_s400", "base": [2000.0, 0, 0, 180, 0, 0]}]
    sb = SceneBuilder(subs, {})
    for name, robot, base in (("arm1", "reis_v15", [0.0] * 6), ("gmf1", "fanuc_s400", [2000.0, 0, 0, 180, 0, 0])):
        m = load_robot(robot).with_base(pose_to_T(*base))
        for _ in range(20):
            counts = rng.integers(-20000, 20000, 6)
            q = m.gearing.counts_to_joints(counts.astype(float))
            frames = sb.link_frames(name, {"encoder_pos": counts.tolist()})
            assert len(frames) == 7
            assert np.allclose(frames[0], pose_to_T(*base))
            assert np.allclose(frames[-1][:3, 3], m.fk(q)[:3, 3], atol=1e-6)


def test_seam_map_from_valid_lead_readings():
    T_wcp_sensor = pose_to_T(0, -100, 250, -90, 90, 180)
    subs = [{"name": "arm1", "class": "arm6r", "robot": "reis_v15", "base": [0.0] * 6},
            {"name": "mvs", "class": "line_laser", "robot": None}]
    sb = SceneBuilder(subs, {"tool_robot": "arm1", "sensor": "mvs", "T_wcp_sensor": T_wcp_sensor.tolist(),
                             "T_wcp_tool": np.eye(4).tolist()})
    wcp = pose_to_T(300, 100, 1340, 0, 180, 0)
    arm = {"x": 300.0, "y": 100.0, "z": 1340.0, "R": wcp[:3, :3].tolist(), "encoder_pos": [0] * 6}
    geo = sb.step({"arm1": arm, "mvs": {"x": 5.0, "y": 2.0, "homed": 0, "stale": 0}})
    S = wcp @ T_wcp_sensor
    assert np.allclose(geo["seam"][0], (S @ [5.0, 2.0, 0, 1])[:3])
    assert np.allclose(geo["frames"]["sensor"], S)
    geo = sb.step({"arm1": arm, "mvs": {"x": 9.0, "y": 9.0, "homed": 1, "stale": 0}})  # invalid: no point
    assert len(geo["seam"]) == 1 and geo["laser"] is not None


def test_observers_import_only_brain_kinematics_and_the_seam_layout():
    """DESIGN §7: observers read the Brain's databases like a task; never a device or the simulator."""
    from tests.layering import DROID, droid_imports, within

    may = ("droid.brain", "droid.kinematics", "droid.cli", "droid.observe", "droid.tasks.seam.layout")
    for path in (DROID / "observe").rglob("*.py"):
        for n in droid_imports(path):
            assert within(n, may), (path, n)


def test_observers_never_write_a_command():
    """Only droid-replay writes databases (into a replay cell); no observer opens a Command to write it."""
    from pathlib import Path

    for path in (Path(__file__).resolve().parents[2] / "droid" / "observe").rglob("*.py"):
        text = path.read_text()
        if path.name == "replay.py":
            continue
        assert ".write(" not in text.replace("w.write(", "").replace("self.write(", "").replace(
            "csv", ""), path
        assert ".update(" not in text, path
