"""ROS 2 bags of recordings (droid-replay --export rosbag2, droid-record --format rosbag2), read back with
rosbags' own reader: counts, types, joint states against the MCAP, TF frames, refusals."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from droid.brain.db.databases import open_brain
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T
from droid.observe.bag import JOINT_NAMES, summary_lines
from droid.observe.mcapfile import read_recording
from droid.observe.replay import main as replay_main
from tests.brain.cellutil import droid, in_process
from tests.observe.test_record import record_ticks


def make_recording(db_cell, tmp_path, n=50):
    """A recording of the sim cell's databases: both arms moving, the lead sensor reading at half the
    tick rate and invalid for a while, the tool-tip sensor never valid, the joystick deflected."""
    cell, _ = db_cell
    dbs = {name: open_brain(cell, cell.subunit(name), "status") for name in ("arm1", "gmf1", "mvs", "tool", "joy")}

    def change(i):
        dbs["arm1"].update(tick=100 + i, x=900.0 + i, y=10.0 - i, z=600.0, encoder_pos=[37 * i, -20 * i, 5 * i, 0, 11 * i, -i])
        dbs["gmf1"].update(tick=100 + i, x=1200.0, z=800.0 + i, encoder_pos=[0, 3 * i, 0, 0, 0, 7 * i])
        if i % 2 == 0:  # a new reading every other tick
            dbs["mvs"].update(tick=100 + i, updated_ns=5_000_000 + i, x=40.0 + 0.1 * i, y=-1.0 + 0.05 * i,
                              homed=1 if 10 <= i < 20 else 0)
        dbs["tool"].update(tick=100 + i, homed=1)
        dbs["joy"].update(tick=100 + i, updated_ns=i, valid=1 if i >= 5 else 0, n_axes=2, n_buttons=3,
                          axes=[0.01 * i, -0.5] + [0.0] * 6, buttons=[i % 2, 0, 1] + [0] * 13)

    path = tmp_path / "rec.mcap"
    record_ticks(cell, str(path), n, change).close()
    for db in dbs.values():
        db.close()
    return path


def read_bag(bag):
    """{topic: [(t_ns, msg)]} and {topic: msgtype} of a bag, through rosbags' AnyReader."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out, types = {}, {}
    with AnyReader([Path(bag)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
        for c in r.connections:
            types[c.topic] = c.msgtype
        for c, t, raw in r.messages():
            out.setdefault(c.topic, []).append((t, r.deserialize(raw, c.msgtype)))
    return out, types


def expected_readings(rec, name, valid):
    """How many new valid readings the MCAP holds for a sensor/joystick (as the bag should publish)."""
    n, last = 0, None
    for f in rec.frames:
        d = f[f"/{name}/status"][0]
        key = (d["tick"], d["updated_ns"])
        if valid(d) and not d["stale"] and key != last:
            n += 1
            last = key
    return n


def joints_rad(robot, d):
    return np.radians(load_robot(robot).gearing.counts_to_joints(np.asarray(d["encoder_pos"], float)))


def T_of(tr):
    """4x4 [m] of a geometry_msgs/Transform."""
    q = tr.rotation
    x, y, z, w = q.x, q.y, q.z, q.w
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = (tr.translation.x, tr.translation.y, tr.translation.z)
    return T


def test_export_reads_back_with_rosbags(db_cell, tmp_path):
    path = make_recording(db_cell, tmp_path)
    rec = read_recording(path)
    bag = tmp_path / "bag"
    out = droid("droid.observe.replay", str(path), "--export", "rosbag2", str(bag))
    assert out.returncode == 0, out.stderr
    msgs, types = read_bag(bag)
    # stdout: one line per topic, with the bag's own counts
    assert out.stdout.splitlines() == summary_lines({t: len(m) for t, m in msgs.items()}, types)
    n = len(rec.ticks)
    assert types == {"/arm1/joint_states": "sensor_msgs/msg/JointState", "/gmf1/joint_states": "sensor_msgs/msg/JointState",
                     "/arm1/tool_pose": "geometry_msgs/msg/PoseStamped", "/gmf1/tool_pose": "geometry_msgs/msg/PoseStamped",
                     "/tf": "tf2_msgs/msg/TFMessage", "/tf_static": "tf2_msgs/msg/TFMessage",
                     "/mvs/reading": "geometry_msgs/msg/PoseStamped", "/joy/joy": "sensor_msgs/msg/Joy",
                     "/rosout": "rcl_interfaces/msg/Log"}  # /tool/reading: never valid, so no topic
    counts = {t: len(m) for t, m in msgs.items()}
    assert counts["/arm1/joint_states"] == counts["/gmf1/joint_states"] == counts["/tf"] == n == 50
    assert counts["/arm1/tool_pose"] == n and counts["/tf_static"] == 1
    assert counts["/mvs/reading"] == expected_readings(rec, "mvs", lambda d: d["homed"] == 0) == 20
    assert counts["/joy/joy"] == expected_readings(rec, "joy", lambda d: d["valid"] == 1) == 45
    assert counts["/rosout"] == sum(len(f.get("/log", [])) for f in rec.frames) > 0
    # first and last joint states equal the MCAP's Status (counts -> rad through the gearing)
    for arm, robot in (("arm1", "reis_v15"), ("gmf1", "fanuc_s400")):
        js = msgs[f"/{arm}/joint_states"]
        for k in (0, -1):
            t, m = js[k]
            d = rec.frames[k][f"/{arm}/status"][0]
            assert list(m.name) == list(JOINT_NAMES)
            assert np.allclose(m.position, joints_rad(robot, d), rtol=0, atol=1e-12)
            assert t == rec.t_ns[k] == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        assert len(js[0][1].velocity) == 0  # no velocity before a second sample
        dt = (rec.t_ns[1] - rec.t_ns[0]) * 1e-9
        assert np.allclose(js[1][1].velocity, (js[1][1].position - js[0][1].position) / dt)
    # the tool pose is the Status pose in metres
    d = rec.frames[-1]["/arm1/status"][0]
    p = msgs["/arm1/tool_pose"][-1][1]
    assert p.header.frame_id == "world"
    assert (p.pose.position.x, p.pose.position.y, p.pose.position.z) == pytest.approx((0.949, -0.039, 0.6))
    # the lead sensor's reading in its frame [m]; the joystick's axes and buttons as the record has them
    r = msgs["/mvs/reading"][-1][1]
    assert r.header.frame_id == "sensor" and r.pose.position.x == pytest.approx(0.0448)
    j = msgs["/joy/joy"][-1][1]
    assert list(j.axes) == pytest.approx([0.49, -0.5]) and list(j.buttons) == [1, 0, 1]


def test_tf_frames_match_the_recording(db_cell, tmp_path):
    path = make_recording(db_cell, tmp_path, n=5)
    rec = read_recording(path)
    bag = tmp_path / "bag"
    assert droid("droid.observe.replay", str(path), "--export", "rosbag2", str(bag)).returncode == 0
    msgs, _ = read_bag(bag)
    static = {tf.child_frame_id: (tf.header.frame_id, T_of(tf.transform)) for tf in msgs["/tf_static"][0][1].transforms}
    dyn = {tf.child_frame_id: (tf.header.frame_id, T_of(tf.transform)) for tf in msgs["/tf"][-1][1].transforms}
    frames = {**static, **dyn}
    assert set(frames) == {"arm1/base", "gmf1/base", "arm1/wcp", "gmf1/wcp", "tool", "sensor", "workpiece"}
    assert frames["arm1/base"][0] == "world" and frames["arm1/wcp"][0] == "arm1/base"
    assert frames["tool"][0] == frames["sensor"][0] == "arm1/wcp" and frames["workpiece"][0] == "gmf1/wcp"
    # gmf1's base is the cell's (2 m along x, turned 180 deg about z)
    cell, _ = db_cell
    assert np.allclose(frames["gmf1/base"][1][:3, 3], np.asarray(cell.subunit("gmf1").base[:3]) / 1000)
    assert np.allclose(frames["gmf1/base"][1][:3, :3], pose_to_T(*cell.subunit("gmf1").base)[:3, :3], atol=1e-12)

    def in_world(name):
        parent, T = frames[name]
        return T if parent == "world" else in_world(parent) @ T

    # every frame, chained to world, is where the recording's own /tf (Foxglove, world-rooted) puts it
    fox = {t["child_frame_id"]: t for t in rec.frames[-1]["/tf"][0]["transforms"]}
    for name in frames:
        f = fox[name]
        assert np.allclose(in_world(name)[:3, 3], [f["translation"][k] for k in "xyz"], atol=1e-9), name


def test_lockstep_trial_joint_states_give_the_tool_pose(tmp_path):
    """A lockstep trial's bag: the forward kinematics of the joint states is the tool pose (a ROS user's
    URDF with the robot file's joint convention sees the arm where the Status says it is)."""
    from droid.experiments.matrix import resolve
    from droid.experiments.trial import run_trial, with_overrides

    path = tmp_path / "t.mcap"
    run_trial(with_overrides(resolve(["1.3"])[0].config, length_mm=30.0), record=str(path))
    bag = tmp_path / "bag"
    assert droid("droid.observe.replay", str(path), "--export", "rosbag2", str(bag)).returncode == 0
    msgs, _ = read_bag(bag)
    reis = load_robot("reis_v15")
    for (_, js), (_, pose) in list(zip(msgs["/arm1/joint_states"], msgs["/arm1/tool_pose"]))[::50]:
        T = reis.fk(np.degrees(js.position))
        p = pose.pose.position
        assert np.allclose(T[:3, 3] / 1000, (p.x, p.y, p.z), atol=1e-3)
    assert len(msgs["/mvs/reading"]) > 0


def test_a_class_without_a_fitting_message_is_named_not_guessed():
    from droid.observe.bag import BagConverter

    meta = {"subunits": [{"name": "ft1", "class": "ft_sensor", "robot": None, "base": [0.0] * 6,
                          "areas": {"status": {"layout": "ft_status", "version": 1}}},
                         {"name": "arm9", "class": "arm6r", "robot": "no_such_robot", "base": [0.0] * 6,
                          "areas": {"status": {"layout": "arm_status", "version": 1}}}]}
    conv = BagConverter(meta)
    assert "no fitting ROS message" in conv.skipped()["ft1"] and "no joint states" in conv.skipped()["arm9"]
    d = {"x": 1000.0, "y": 0.0, "z": 0.0, "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "encoder_pos": [0] * 6}
    topics = [t for t, _, _ in conv.step(0, {"ft1": {"x": 1.0}, "arm9": d})]
    assert topics == ["/arm9/tool_pose", "/tf"]  # the pose without joint states; nothing for ft1


def test_export_a_tick_range(db_cell, tmp_path):
    path = make_recording(db_cell, tmp_path, n=20)
    bag = tmp_path / "bag"
    out = droid("droid.observe.replay", str(path), "--export", "rosbag2", "--out", str(bag), "--from", "105", "--to", "109")
    assert out.returncode == 0, out.stderr
    msgs, _ = read_bag(bag)
    assert len(msgs["/arm1/joint_states"]) == 5 and len(msgs["/tf_static"]) == 1


def test_existing_dir_refused_then_force_replaces(db_cell, tmp_path, capsys):
    path = make_recording(db_cell, tmp_path, n=5)
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "keep.txt").write_text("mine")
    out = in_process(replay_main, capsys, str(path), "--export", "rosbag2", str(bag))
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1 and "exists" in out.stderr
    # --force replaces a bag or an empty directory only, never another directory
    out = in_process(replay_main, capsys, str(path), "--export", "rosbag2", str(bag), "--force")
    assert out.returncode == 2 and "not a ROS 2 bag" in out.stderr and (bag / "keep.txt").read_text() == "mine"
    os.remove(bag / "keep.txt")
    assert in_process(replay_main, capsys, str(path), "--export", "rosbag2", str(bag), "--force").returncode == 0
    first = sorted(os.listdir(bag))
    assert first == ["bag.mcap", "metadata.yaml"]
    out = in_process(replay_main, capsys, str(path), "--export", "rosbag2", str(bag))
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1
    (tmp_path / "s").mkdir()
    short = make_recording(db_cell, tmp_path / "s", n=3)
    out = in_process(replay_main, capsys, str(short), "--export", "rosbag2", str(bag), "--force")
    assert out.returncode == 0, out.stderr
    msgs, _ = read_bag(bag)
    assert len(msgs["/arm1/joint_states"]) == 3  # replaced, not appended
    assert not [p for p in os.listdir(tmp_path) if "partial" in p]


@pytest.mark.parametrize("damage", ["truncated", "not_mcap", "missing"])
def test_bad_recording_refused_and_nothing_written(db_cell, tmp_path, damage):
    path = make_recording(db_cell, tmp_path, n=5)
    bad = tmp_path / "bad.mcap"
    if damage == "truncated":
        bad.write_bytes(path.read_bytes()[:-200])
    elif damage == "not_mcap":
        bad.write_text("hello\n")
    bag = tmp_path / "bag"
    out = droid("droid.observe.replay", str(bad), "--export", "rosbag2", str(bag))
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert not bag.exists() and not [p for p in os.listdir(tmp_path) if "partial" in p]


def test_bad_export_arguments(db_cell, tmp_path, capsys):
    path = make_recording(db_cell, tmp_path, n=3)
    for args in (["--export", "rosbag2"], ["--export", "rosbag2", str(tmp_path / "b"), "--subunit", "arm1"],
                 ["--force"], [str(tmp_path / "b")], ["--export", "rosbag2", str(tmp_path)]):
        out = in_process(replay_main, capsys, str(path), *args)
        assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, (args, out.stderr)
    out = in_process(replay_main, capsys, str(path), "--export", "rosbag2", str(tmp_path / "no" / "bag"))
    assert out.returncode == 2 and "does not exist" in out.stderr


def test_record_writes_a_bag_directly(db_cell, tmp_path):
    """droid-record --format rosbag2's recorder on a cell's databases (no live cell: ticks given by hand)."""
    from droid.observe.record import LiveRecorder

    cell, cf = db_cell
    arm = open_brain(cell, cell.subunit("arm1"), "status")
    bag = tmp_path / "bag"
    rec = LiveRecorder(cell, str(bag), fmt="rosbag2")
    try:
        for i in range(12):
            arm.update(encoder_pos=[100 * i, 0, 0, 0, 0, 0], x=800.0 + i)
            rec.on_tick(200 + i)
    finally:
        rec.close()
        arm.close()
    msgs, types = read_bag(bag)
    assert len(msgs["/arm1/joint_states"]) == len(msgs["/tf"]) == 12 and len(msgs["/tf_static"]) == 1
    q = msgs["/arm1/joint_states"][-1][1].position
    want = np.radians(load_robot("reis_v15").gearing.counts_to_joints([1100, 0, 0, 0, 0, 0]))
    assert np.allclose(q, want) and q[0] != 0
    assert msgs["/arm1/tool_pose"][-1][1].pose.position.x == pytest.approx(0.811)
    # the CLI refuses an existing directory before recording anything (exit 2, one line)
    out = droid("droid.observe.record", "--format", "rosbag2", "--out", str(bag), "--cell", str(cf), "--seconds", "1")
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1 and "exists" in out.stderr
    out = droid("droid.observe.record", "--out", str(tmp_path / "x.mcap"), "--force", "--cell", str(cf))
    assert out.returncode == 2 and "--force" in out.stderr
