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


def test_observers_import_only_brain_kinematics_and_cli():
    """docs/design.md §7: observers read the Brain's databases like a task; never a device, a task or the
    simulator (the seam layout is cell geometry: droid.brain.cell.cell_layout)."""
    from tests.layering import DROID, droid_imports, within

    may = ("droid.brain", "droid.kinematics", "droid.cli", "droid.observe")
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
        # file writers are allowed (an MCAP writer, a CSV, a ROS 2 bag's writer: bag.py's self.bag)
        assert ".write(" not in text.replace("w.write(", "").replace("self.write(", "").replace(
            "csv", "").replace("self.bag.write(", ""), path
        assert ".update(" not in text, path


# ---------------------------------------------------------------- bodies (issue 29 item 2)
def test_link_radii_from_the_robot_file():
    """r = sqrt(2 I_min / m): the files' inertias are uniform cylinders (reis_v15: column r 0.2 m,
    upper arm and forearm 0.1 m, roll tube 0.06 m); without [dynamics], a fraction of the longest link."""
    from dataclasses import replace

    from droid.observe.scene import BODY_FALLBACK_FRACTION, link_radii_mm

    r = link_radii_mm(load_robot("reis_v15"))
    assert np.allclose(r[:4], [200.0, 100.0, 100.0, 60.0], atol=0.5)
    f = link_radii_mm(load_robot("fanuc_s400"))
    assert np.allclose(f[:4], [300.0, 150.0, 120.0, 100.0], atol=0.5)
    bare = replace(load_robot("reis_v15"), dynamics=None)
    assert np.allclose(link_radii_mm(bare), BODY_FALLBACK_FRACTION * 725.0)


def test_arm_bodies_run_from_the_base_to_the_wrist_centre():
    """The capsules follow the D-H offsets: they chain from the base to the FK wrist centre, the column
    d1 long, the upper arm a2, the forearm d4, each with its own link's radius; they move with the joints."""
    from droid.observe.scene import arm_bodies, link_radii_mm

    rng = np.random.default_rng(7)
    m = load_robot("reis_v15").with_base(pose_to_T(100.0, 50.0, 0.0, 30.0, 0.0, 0.0))
    sub = {"name": "arm1", "class": "arm6r", "robot": "reis_v15", "base": [100.0, 50.0, 0, 30.0, 0, 0]}
    sb = SceneBuilder([sub], {})
    radii = link_radii_mm(m)
    last = None
    for _ in range(10):
        counts = rng.integers(-20000, 20000, 6)
        q = m.gearing.counts_to_joints(counts.astype(float))
        caps = arm_bodies(sb.link_frames("arm1", {"encoder_pos": counts.tolist()}), m.dh.d_mm, radii)
        long = [c for c in caps if np.linalg.norm(np.subtract(c[3:6], c[0:3])) > 1.0]
        assert [round(np.linalg.norm(np.subtract(c[3:6], c[0:3]))) for c in long] == [725, 600, 540]
        assert [c[6] for c in long] == [round(radii[0], 1), round(radii[1], 1), round(radii[2], 1)]
        assert np.allclose(long[0][0:3], [100.0, 50.0, 0.0], atol=0.1)
        for a, b in zip(long, long[1:]):
            assert np.allclose(a[3:6], b[0:3], atol=0.1)
        assert np.allclose(long[-1][3:6], m.fk(q)[:3, 3], atol=0.1)
        balls = [c for c in caps if c not in long]  # links without length: the elbow's (3), the wrist's (5)
        assert len(balls) == 2 and all(c[0:3] == c[3:6] for c in balls)
        assert np.allclose(balls[0][0:3], long[1][3:6], atol=0.1) and balls[0][6] == round(radii[2], 1)
        assert np.allclose(balls[1][0:3], m.fk(q)[:3, 3], atol=0.1) and balls[1][6] == round(radii[4], 1)
        assert caps != last
        last = caps


def _cell_scene():
    T_wcp_sensor = pose_to_T(0, -100, 250, -90, 90, 180)
    subs = [{"name": "arm1", "class": "arm6r", "robot": "reis_v15", "base": [0.0] * 6},
            {"name": "gmf1", "class": "arm6r", "robot": "fanuc_s400", "base": [2000.0, 0, 0, 180, 0, 0]},
            {"name": "mvs", "class": "line_laser", "robot": None},
            {"name": "ft", "class": "anything", "robot": None}]
    scene = {"tool_robot": "arm1", "holder_robot": "gmf1", "sensor": "mvs", "T_wcp_sensor": T_wcp_sensor.tolist(),
             "T_wcp_tool": pose_to_T(0, 0, 250, -90, 90, 180).tolist(),
             "T_wcp_workpiece": pose_to_T(50, -350, 150, 0, 90, 90).tolist()}
    wcp = pose_to_T(300, 100, 1340, 0, 180, 0)
    arm = {"x": 300.0, "y": 100.0, "z": 1340.0, "R": wcp[:3, :3].tolist(), "encoder_pos": [0] * 6}
    hold_T = pose_to_T(1200, 0, 1200, 0, 90, 0)
    hold = {"x": 1200.0, "y": 0.0, "z": 1200.0, "R": hold_T[:3, :3].tolist(), "encoder_pos": [0] * 6}
    return SceneBuilder(subs, scene), wcp, {"arm1": arm, "gmf1": hold, "mvs": {"x": 1.0, "y": 0.0, "homed": 0, "stale": 0}}


def test_tool_sensor_and_fixture_bodies_from_the_mounts():
    from droid.observe.scene import SENSOR_STANDOFF_MM

    sb, wcp, st = _cell_scene()
    geo = sb.step(st)
    b = geo["bodies"]
    assert set(b) == {"arm1", "gmf1", "torch", "bracket", "fixture"}
    tool = wcp @ pose_to_T(0, 0, 250, -90, 90, 180)
    assert np.allclose(b["torch"][0][0:3], wcp[:3, 3], atol=0.1)
    assert np.allclose(b["torch"][0][3:6], tool[:3, 3], atol=0.1)
    head = geo["frames"]["sensor"] @ [-SENSOR_STANDOFF_MM, 0, 0, 1]
    assert np.allclose(geo["laser_src"], head[:3]) and np.allclose(b["bracket"][0][3:6], head[:3], atol=0.1)
    assert np.allclose(b["fixture"][0][0:3], [1200.0, 0.0, 1200.0], atol=0.1)


def test_force_arrow_keyed_on_the_status_fields():
    """Any subunit whose Status has force_N [N] / torque_Nm [N m] (a force/torque sensor of whatever class):
    an arrow at the tool point, its vectors turned from the tool arm's wrist axes to global; none when stale."""
    sb, wcp, st = _cell_scene()
    assert sb.step(st)["forces"] == []
    st["ft"] = {"force_N": [10.0, -5.0, 40.0], "torque_Nm": [0.5, 0.0, -0.25], "stale": 0}
    geo = sb.step(st)
    (f,) = geo["forces"]
    assert f["subunit"] == "ft"
    assert np.allclose(f["at"], geo["frames"]["tool"][:3, 3], atol=0.1)
    assert np.allclose(f["force_N"], wcp[:3, :3] @ [10.0, -5.0, 40.0], atol=1e-3)
    assert np.allclose(f["torque_Nm"], wcp[:3, :3] @ [0.5, 0.0, -0.25], atol=1e-3)
    st["ft"]["stale"] = 1
    assert sb.step(st)["forces"] == []
    st["ft"] = {"force_N": [float("nan"), 0, 0], "stale": 0}
    assert sb.step(st)["forces"] == []


def test_scene_meta_reads_the_cells_mounts(tmp_path):
    """tool_pose / sensor_pose / workpiece_mount / workpiece of the cell's world devices (cells/sim.toml)."""
    from droid.brain.cell.cellfile import load_cell
    from droid.observe.scene import scene_meta
    from tests.brain.cellutil import make_cell_file

    text = make_cell_file(tmp_path, "sm").read_text()
    text = text.replace("tool_pose = [0.0, 0.0, 250.0,", "tool_pose = [0.0, 0.0, 260.0,")
    path = tmp_path / "sm2.toml"
    path.write_text(text)
    g = scene_meta(load_cell(path))
    assert np.allclose(g["T_wcp_tool"], pose_to_T(0, 0, 260, -90, 90, 180))
    assert np.allclose(g["T_wcp_sensor"], pose_to_T(0, -100, 250, -90, 90, 180))
    assert np.allclose(g["T_wcp_workpiece"], pose_to_T(50, -350, 150, 0, 90, 90))
    assert g["workpiece"] == "step_input"


def test_a_live_cell_shows_the_workpiece_the_world_published(tmp_path):
    """droid-sim's camera twin writes the workpiece's mesh into the run directory when the cell's
    world is built there; droid-web's live source reads it (plain data, no import of droid.sim)."""
    from droid.brain.cell.cellfile import load_cell
    from droid.observe.scene import live_workpiece_mesh
    from droid.sim.mvs.devices import publish_workpiece_mesh
    from droid.sim.workpiece import load_workpiece
    from tests.brain.cellutil import make_cell_file

    cell = load_cell(make_cell_file(tmp_path, "meshcell"))
    assert live_workpiece_mesh(cell) is None  # no run directory yet: nothing published, nothing read
    cell.run_dir.mkdir(parents=True)
    publish_workpiece_mesh(type("W", (), {"cell": cell})(), load_workpiece("step_input"))
    mesh = live_workpiece_mesh(cell)
    assert mesh is not None and mesh["name"] == "step_input"
    assert len(mesh["points"]) == 3 * mesh["sections"] * mesh["per_section"]
    (cell.run_dir / "workpiece_mesh.json").write_text('{"points": "garbled"}')
    assert live_workpiece_mesh(cell) is None  # not a mesh: ignored, never a crash
