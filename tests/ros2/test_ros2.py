"""droid-ros2 against a plain rclpy node (issue 42): a cell's Brain databases with no program, Status
written by the test, droid-ros2 as a process, and tests/ros2/plain_probe.py (rclpy and message
packages only, no DROID code) as another.  No timing verdicts: generous waits for discovery."""
from __future__ import annotations

import importlib.util
import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from droid.brain.db.databases import open_brain
from droid.kinematics import load_robot
from tests.brain.cellutil import reaped

ROOT = Path(__file__).resolve().parents[2]
PROBE = Path(__file__).with_name("plain_probe.py")
HAVE_RCLPY = importlib.util.find_spec("rclpy") is not None
needs_rclpy = pytest.mark.skipif(not HAVE_RCLPY, reason="the ros2 extra is not installed (pip install 'droid[ros2]')")
DISCOVERY_S = 40.0
COUNTS = [12000, -8000, 15000, 2000, -3000, 4000]
JOINTS = [f"joint_{i}" for i in range(1, 7)]


def ros_env(domain: int) -> dict:
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")


@pytest.fixture
def domain() -> int:
    # not 0 (never another ROS 2 system's default), and <= 101: on Linux, Fast DDS's ports for higher ids
    # fall in the ephemeral port range (ROS 2's "The ROS_DOMAIN_ID" guide), where a port may be taken
    return random.randint(20, 101)


def write_statuses(cell, homed: int = 1) -> None:
    now = time.monotonic_ns()
    for arm, counts in (("arm1", COUNTS), ("gmf1", [0] * 6)):
        db = open_brain(cell, cell.subunit(arm), "status")
        try:
            db.update(encoder_pos=counts, homed=homed, x=1100.0, y=50.0, z=900.0, R=10.0, tick=7, updated_ns=now,
                      stale=0, fault=0, busy=0)
        finally:
            db.close()
    db = open_brain(cell, cell.subunit("ft"), "status")
    try:
        db.update(force_N=[1.5, -2.0, 30.0], torque_Nm=[0.1, 0.2, -0.3], valid=1, stale=0, tick=7, updated_ns=now)
    finally:
        db.close()
    db = open_brain(cell, cell.subunit("mvs"), "status")
    try:
        db.update(x=12.5, y=-1.25, z=0.0, R=0.0, homed=0, stale=0, tick=7, updated_ns=now)
    finally:
        db.close()


def start_node(path, domain: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "droid.ros2.node", "--cell", str(path), *extra], cwd=ROOT,
                            env=ros_env(domain), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def stop_node(proc: subprocess.Popen) -> tuple[int, str]:
    proc.send_signal(signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return proc.returncode, err


def probe(domain: int, *args: str, timeout: float = 120.0) -> dict:
    out = subprocess.run([sys.executable, str(PROBE), *args], env=ros_env(domain), capture_output=True, text=True,
                         timeout=timeout, cwd="/")
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def command_snapshot(cell) -> dict:
    snap = {}
    for arm in ("arm1", "gmf1"):
        db = open_brain(cell, cell.subunit(arm), "command")
        try:
            snap[arm] = db.read().tobytes()
        finally:
            db.close()
    return snap


def kin_urdf(path, arm: str) -> str:
    out = subprocess.run([sys.executable, "-m", "droid.kinematics.cli", "urdf", "--cell", str(path), "--subunit", arm],
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout


# ------------------------------------------------------------------ no ROS needed


def test_without_the_extra_one_line_naming_it(monkeypatch, capsys):
    from droid.ros2 import env, node

    monkeypatch.setattr(env, "installed", lambda: False)
    assert node.main([]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'droid[ros2]'" in err[0], err


@pytest.mark.parametrize("argv", [["--domain", "233"], ["--domain", "-1"], ["--domain", "x"], ["--seconds", "nan"],
                                  ["--nope"]])
def test_bad_arguments_exit_2(argv):
    out = subprocess.run([sys.executable, "-m", "droid.ros2.node", *argv], capture_output=True, text=True, cwd=ROOT,
                         timeout=60)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr


@needs_rclpy
def test_cell_not_up_exit_1_one_line(tmp_path, cell_name):
    from tests.brain.cellutil import make_cell_file

    path = make_cell_file(tmp_path, cell_name)  # no database created
    out = subprocess.run([sys.executable, "-m", "droid.ros2.node", "--cell", str(path), "--domain", "21"],
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 1, out.stderr
    assert len(out.stderr.strip().splitlines()) == 1, out.stderr


def test_bad_ros_domain_id_in_the_environment(monkeypatch, capsys):
    from droid.ros2 import node

    monkeypatch.setenv("ROS_DOMAIN_ID", "seven")
    assert node.main([]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ROS_DOMAIN_ID" in err[0]


def test_domain_from_the_flag_then_the_cell_file_then_the_environment(tmp_path):
    from types import SimpleNamespace

    from droid.brain.cell.cellfile import builtin_cell_path, load_cell
    from droid.ros2.node import domain_of

    p = tmp_path / "c.toml"
    p.write_text(builtin_cell_path().read_text() + "\n[ros2]\ndomain_id = 42\n")
    cell, plain = load_cell(p), load_cell(builtin_cell_path())
    assert domain_of(SimpleNamespace(domain=7), cell, {"ROS_DOMAIN_ID": "9"}) == 7
    assert domain_of(SimpleNamespace(domain=None), cell, {"ROS_DOMAIN_ID": "9"}) == 42
    assert domain_of(SimpleNamespace(domain=None), plain, {"ROS_DOMAIN_ID": "9"}) == 9
    assert domain_of(SimpleNamespace(domain=None), plain, {}) == 0
    p.write_text(builtin_cell_path().read_text() + "\n[ros2]\ndomain_id = 300\n")
    with pytest.raises(Exception, match="domain id"):
        load_cell(p)


def test_environment_is_loopback_unless_subnet():
    from droid.ros2.env import ros_environment

    e = {"ROS_STATIC_PEERS": "192.0.2.1"}
    v = ros_environment(5, False, e)
    assert e["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST" and e["ROS_DOMAIN_ID"] == "5"
    assert "ROS_STATIC_PEERS" not in e and v["RMW_IMPLEMENTATION"] == "rmw_fastrtps_cpp"
    assert ros_environment(5, True, {})["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET"


def _arm():
    from droid.brain.cell.cellfile import builtin_cell_path, load_cell
    from droid.tasks.arm import BrainArm

    return BrainArm(load_cell(builtin_cell_path()), "arm1")


@pytest.mark.parametrize("names, points, why", [
    (JOINTS, [], "empty trajectory"),
    (["a", "b", "c", "d", "e", "f"], [([0.0] * 6, 2.0)], "wrong joint names"),
    (JOINTS[:5], [([0.0] * 5, 2.0)], "wrong joint names"),
    (JOINTS[:5] + ["joint_1"], [([0.0] * 6, 2.0)], "given twice"),
    (JOINTS, [([0.0, float("nan"), 0, 0, 0, 0], 2.0)], "not a finite number"),
    (JOINTS, [([0.0, 0, float("inf"), 0, 0, 0], 2.0)], "not a finite number"),
    (JOINTS, [([0.0] * 5, 2.0)], "5 positions for 6"),
    (JOINTS, [([0.0] * 6, 0.0)], "time_from_start"),
    (JOINTS, [([0.0] * 6, 2.0), ([0.0] * 6, 1.0)], "time_from_start"),
    (JOINTS, [([1.5, 0, 0, 0, 0, 0], 0.1)], "too fast"),
    (JOINTS, [([0.0] * 6, 1e-4)], "shorter than one heartbeat tick"),
    (JOINTS, [([9.0, 0, 0, 0, 0, 0], 100.0)], "outside"),
])
def test_plan_refuses(names, points, why):
    from droid.cli import BadInput
    from droid.ros2.trajectory import plan

    with pytest.raises(BadInput, match=why):
        plan(_arm(), names, points, np.zeros(6))


def test_plan_one_move_per_segment_in_its_time():
    from droid.ros2.trajectory import plan

    arm = _arm()
    order = [2, 0, 1, 3, 4, 5]  # any order of the names
    names = [JOINTS[i] for i in order]
    q1 = [0.1, 0.2, -0.1, 0.3, 0.0, 0.5]
    q2 = [0.2, 0.1, 0.0, 0.0, 0.1, 0.0]
    legs = plan(arm, names, [([q1[i] for i in order], 1.5), ([q2[i] for i in order], 4.0)], np.zeros(6))
    assert [leg.seconds for leg in legs] == [1.5, 2.5] and [leg.t_end_s for leg in legs] == [1.5, 4.0]
    want = np.rint(arm.model.gearing.joints_to_counts(np.degrees(q2)))
    assert np.array_equal(legs[1].counts, want)


# ------------------------------------------------------------------ against a plain rclpy node

WANT = {"/arm1/joint_states": "sensor_msgs/msg/JointState", "/gmf1/joint_states": "sensor_msgs/msg/JointState",
        "/arm1/tool_pose": "geometry_msgs/msg/PoseStamped", "/tcp_pose": "geometry_msgs/msg/PoseStamped",
        "/ft/wrench": "geometry_msgs/msg/WrenchStamped", "/mvs/reading": "geometry_msgs/msg/PoseStamped",
        "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray", "/cell_markers": "visualization_msgs/msg/MarkerArray",
        "/arm1/robot_description": "std_msgs/msg/String", "/gmf1/robot_description": "std_msgs/msg/String"}


@needs_rclpy
def test_a_plain_rclpy_node_decodes_every_type(db_cell, domain, tmp_path):
    cell, path = db_cell
    write_statuses(cell)
    out = tmp_path / "got.json"
    done = threading.Event()

    def new_readings():  # a laser reading is published when it is new: the sensor keeps reading
        db = open_brain(cell, cell.subunit("mvs"), "status")
        try:
            k = 8
            while not done.wait(0.05):
                db.update(tick=k, updated_ns=time.monotonic_ns())
                k += 1
        finally:
            db.close()

    th = threading.Thread(target=new_readings)
    th.start()
    try:
        with reaped(start_node(path, domain)) as proc:
            res = probe(domain, "listen", str(out), str(DISCOVERY_S), *[f"{t}={ty}" for t, ty in WANT.items()])
            code, err = stop_node(proc)
    finally:
        done.set()
        th.join()
    assert code == 0, err
    assert res["missing"] == [], (res, err)
    got = json.loads(out.read_text())["messages"]
    # joint positions: what was written, through the robot's gearing [rad]
    js = got["/arm1/joint_states"]
    assert js["name"] == JOINTS
    want = np.radians(load_robot("reis_v15").gearing.counts_to_joints(np.asarray(COUNTS, float)))
    assert np.allclose(js["position"], want, rtol=0, atol=1e-12)
    # the Status pose in metres, the wrench as written, the laser reading
    p = got["/arm1/tool_pose"]["pose"]["position"]
    assert got["/arm1/tool_pose"]["header"]["frame_id"] == "world"
    assert np.allclose([p["x"], p["y"], p["z"]], [1.1, 0.05, 0.9])
    w = got["/ft/wrench"]["wrench"]
    assert np.allclose([w["force"]["x"], w["force"]["y"], w["force"]["z"]], [1.5, -2.0, 30.0])
    r = got["/mvs/reading"]
    assert r["header"]["frame_id"] == "sensor" and np.isclose(r["pose"]["position"]["x"], 0.0125)
    names = {s["name"]: s for s in got["/diagnostics"]["status"]}
    assert names["droid/arm1"]["level"] == 0 and names["droid/arm1"]["message"] == "live", names["droid/arm1"]
    assert {"droid/arm1", "droid/gmf1", "droid/ft", "droid/mvs"} <= set(names)
    ns = {m["ns"] for m in got["/cell_markers"]["markers"]}
    assert {"bodies/arm1", "workpiece", "laser_plane", "seam"} <= ns
    # robot_description: exactly droid-kin urdf, and yourdfpy reads the same robot from both
    yourdfpy = pytest.importorskip("yourdfpy")
    for arm in ("arm1", "gmf1"):
        text = got[f"/{arm}/robot_description"]["data"]
        ref = kin_urdf(path, arm)
        assert text == ref
        a, b = (tmp_path / f"{arm}_ros.urdf"), (tmp_path / f"{arm}_kin.urdf")
        a.write_text(text)
        b.write_text(ref)
        ua, ub = yourdfpy.URDF.load(str(a)), yourdfpy.URDF.load(str(b))
        assert ua.actuated_joint_names == ub.actuated_joint_names == JOINTS
        ua.update_cfg(np.asarray(want))
        ub.update_cfg(np.asarray(want))
        assert np.allclose(ua.get_transform("tool0"), ub.get_transform("tool0"))


@needs_rclpy
def test_without_allow_commands_no_command_topic_or_service(db_cell, domain):
    cell, path = db_cell
    write_statuses(cell)
    with reaped(start_node(path, domain)) as proc:
        # wait for discovery of the node's publishers, then look at the whole graph: the graph probe is a
        # new participant, so it waits (up to DISCOVERY_S) until it too sees the node's topic, then 5 s
        # more for the node's other endpoints (under load, 3 s of discovery was once too few: CI)
        heard = probe(domain, "listen", "/dev/null", str(DISCOVERY_S), "/arm1/joint_states=sensor_msgs/msg/JointState")
        g = probe(domain, "graph", str(DISCOVERY_S), "/arm1/joint_states", "5")
        code, err = stop_node(proc)
    assert code == 0, err
    assert heard["missing"] == [], heard
    assert "/arm1/joint_states" in g["topics"]
    assert not [t for t in g["topics"] if t.endswith(("joint_trajectory", "command_status"))], g["topics"]
    assert not [s for s in g["services"] if s.endswith(("/home", "/stop"))], g["services"]
    assert "commands off" in err


BAD = [
    ({"joint_names": ["a", "b", "c", "d", "e", "f"], "points": [[[0.0] * 6, 2.0]]}, "wrong joint names"),
    ({"joint_names": JOINTS, "points": [[[0.0, float("nan"), 0, 0, 0, 0], 2.0]]}, "not a finite number"),
    ({"joint_names": JOINTS, "points": [[[1.5, 0, 0, 0, 0, 0], 0.1]]}, "too fast"),
    ({"joint_names": JOINTS, "points": [[[9.0, 0, 0, 0, 0, 0], 100.0]]}, "outside"),
    ({"joint_names": JOINTS, "points": []}, "empty trajectory"),
]


@needs_rclpy
def test_bad_trajectories_refused_nothing_written(db_cell, domain):
    cell, path = db_cell
    write_statuses(cell)
    before = command_snapshot(cell)
    results = []
    with reaped(start_node(path, domain, "--allow-commands")) as proc:
        for spec, _ in BAD:
            results.append(probe(domain, "trajectory", "arm1", str(DISCOVERY_S), json.dumps(spec)))
        code, err = stop_node(proc)
    assert code == 0, err
    for (spec, why), res in zip(BAD, results):
        st = [s for s in res["status"] if s["command"] == "trajectory"]
        assert st and st[-1]["state"] == "refused" and why in st[-1]["reason"], (why, res)
    refusals = [ln for ln in err.splitlines() if "refused" in ln]
    assert len(refusals) == len(BAD), err
    assert command_snapshot(cell) == before  # not one byte of any Command changed


@needs_rclpy
def test_not_homed_refused(db_cell, domain):
    cell, path = db_cell
    write_statuses(cell, homed=0)
    before = command_snapshot(cell)
    with reaped(start_node(path, domain, "--allow-commands")) as proc:
        res = probe(domain, "trajectory", "arm1", str(DISCOVERY_S),
                    json.dumps({"joint_names": JOINTS, "points": [[[0.01] * 6, 2.0]]}))
        code, err = stop_node(proc)
    assert code == 0, err
    assert res["status"][-1]["state"] == "refused" and "not homed" in res["status"][-1]["reason"], res
    assert command_snapshot(cell) == before


@needs_rclpy
def test_a_good_trajectory_becomes_droid_moves_command_and_stop_ends_it(db_cell, domain):
    """No agent answers here: the first segment's joint command is written as droid-move writes it
    (target counts, its ticks), then /arm1/stop writes a stop over it and the status says stopped."""
    from droid.brain.db import arm_command

    cell, path = db_cell
    write_statuses(cell)
    q_now = load_robot("reis_v15").gearing.counts_to_joints(np.asarray(COUNTS, float))
    q1 = np.radians(q_now + [1.0, -1.0, 0.5, 0.0, 0.0, 2.0])
    q2 = np.radians(q_now + [2.0, -2.0, 1.0, 0.0, 0.0, 4.0])
    spec = {"joint_names": JOINTS, "points": [[q1.tolist(), 1.0], [q2.tolist(), 2.5]], "until_started": True}
    with reaped(start_node(path, domain, "--allow-commands")) as proc:
        res = probe(domain, "trajectory", "arm1", str(DISCOVERY_S), json.dumps(spec))
        db = open_brain(cell, cell.subunit("arm1"), "command")
        try:
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline and not int(db.read()["sent"]):
                time.sleep(0.05)
            cmd = db.read().copy()
        finally:
            db.close()
        stop = probe(domain, "trigger", "/arm1/stop", str(DISCOVERY_S))
        time.sleep(1.0)
        db = open_brain(cell, cell.subunit("arm1"), "command")
        try:
            after = db.read().copy()
        finally:
            db.close()
        code, err = stop_node(proc)
    assert code == 0, err
    assert res["status"][0]["state"] == "started" and res["status"][0]["points"] == 2, res
    want = np.rint(load_robot("reis_v15").gearing.joints_to_counts(np.degrees(q1)))
    assert int(cmd["sent"]) == 1 and np.array_equal(np.asarray(cmd["encoder_pos"]), want)
    assert int(cmd["joint_time_count"]) == arm_command.ticks_for(1.0, cell.heartbeat_hz)
    assert stop["success"] is True, stop
    assert int(after["cmd_id"]) > int(cmd["cmd_id"])  # a stop was written over the move


# ------------------------------------------------------------------ the bag export and the live topics


@needs_rclpy
def test_live_messages_are_the_bags_message_definitions(db_cell):
    """Every message droid-ros2 publishes, serialized by rclpy (CDR, the wheels' Kilted definitions),
    decodes with the ROS 2 bag export's type store (rosbags, Jazzy), and what rosbags serializes of it
    decodes in rclpy to an equal message; the topics both write (joint states, tool poses, laser
    readings) hold the same values."""
    from rclpy.serialization import deserialize_message, serialize_message

    from droid.observe.bag import BagConverter, typestore
    from droid.observe.mcapfile import cell_meta
    from droid.observe.scene import scene_meta
    from droid.ros2.node import Feed, StatusReader

    cell, _ = db_cell
    write_statuses(cell)
    reader = StatusReader(cell)
    try:
        st = reader.read()
    finally:
        reader.close()
    meta = cell_meta(cell, "live", scene_meta(cell))
    feed = Feed(cell, meta)
    msgs, geo = feed.tick(st)
    msgs += [("/diagnostics", feed.diagnostics(st, {"programs": []})), ("/cell_markers", feed.markers(geo))]
    ts = typestore()
    live = {}
    for topic, m in msgs:
        typ = type(m).__module__.split(".")[0] + "/msg/" + type(m).__name__
        raw = bytes(serialize_message(m))
        assert raw[:4] == b"\x00\x01\x00\x00", topic  # plain CDR, little endian: what a bag stores
        msgdef = ts.get_msgdef(typ)
        back, pos = msgdef.deserialize_cdr_le(raw[4:], 0, msgdef.cls, ts)
        assert len(raw) - 4 - pos < 16, topic  # rclpy's buffer may end in alignment padding
        wire = deserialize_message(raw, type(m))  # as a subscriber gets it (float32 fields rounded)
        assert deserialize_message(bytes(ts.serialize_cdr(back, typ)), type(m)) == wire, topic
        live[topic] = back
    assert {"/arm1/joint_states", "/arm1/tool_pose", "/ft/wrench", "/mvs/reading", "/cell_markers"} <= set(live)
    bag = {topic: m for topic, _, m in BagConverter(meta, ts).step(1_000_000_000, st)}
    for topic in ("/arm1/joint_states", "/gmf1/joint_states"):
        assert list(bag[topic].name) == list(live[topic].name)
        assert np.allclose(bag[topic].position, live[topic].position, rtol=0, atol=1e-12)
    for topic in ("/arm1/tool_pose", "/mvs/reading"):
        a, b = bag[topic].pose, live[topic].pose
        assert bag[topic].header.frame_id == live[topic].header.frame_id, topic
        assert np.allclose([a.position.x, a.position.y, a.position.z], [b.position.x, b.position.y, b.position.z]), topic


def test_setup_writes_the_urdfs_and_the_tf_lines(tmp_path, capsys):
    """--setup needs no ROS: the arms' URDFs as droid-kin urdf writes them and, per arm, a
    static_transform_publisher of world -> <arm>/base_link (the cell's base) and a robot_state_publisher."""
    from droid.brain.cell.cellfile import builtin_cell_path
    from droid.ros2 import node

    path = builtin_cell_path()
    out = tmp_path / "setup"
    assert node.main(["--setup", str(out), "--cell", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    for arm in ("arm1", "gmf1"):
        assert (out / f"{arm}.urdf").read_text() == kin_urdf(path, arm)
        assert any(f"--child-frame-id {arm}/base_link" in ln for ln in lines)
        assert any(f"__ns:=/{arm} -p frame_prefix:={arm}/" in ln for ln in lines)
    gmf = next(ln for ln in lines if "gmf1/base_link" in ln).split()
    assert gmf[gmf.index("--x") + 1] == "2"  # the cell's base of gmf1: 2000 mm along x, turned 180 deg
    assert abs(abs(float(gmf[gmf.index("--qz") + 1])) - 1.0) < 1e-9


class FakeAgent:
    """Stands in for arm1's agent and controller, in a thread of the test (no program of the cell):
    each command it takes (``sent`` cleared), a move lands at once at its target, a home sets
    HOMED; the Status says the command finished.  Keeps the commands it took."""

    def __init__(self, cell) -> None:
        self.cell = cell
        self.taken: list[dict] = []
        self.done = threading.Event()
        self.th = threading.Thread(target=self.run)

    def run(self) -> None:
        from droid.brain.db.layouts import CMD_OK, HOME_MODE, STOP_TICKS

        st = open_brain(self.cell, self.cell.subunit("arm1"), "status")
        cmd = open_brain(self.cell, self.cell.subunit("arm1"), "command")
        tick = 100
        try:
            while not self.done.wait(0.01):
                tick += 1
                c = cmd.read()
                fields = {"tick": tick, "updated_ns": time.monotonic_ns()}
                if int(c["sent"]):
                    cid = int(c["cmd_id"])
                    self.taken.append({"cmd_id": cid, "cmd_mode": int(c["cmd_mode"]),
                                       "encoder_pos": np.asarray(c["encoder_pos"]).tolist(),
                                       "joint_time_count": int(c["joint_time_count"])})
                    cmd.update(sent=0)
                    if int(c["cmd_mode"]) == int(HOME_MODE):
                        fields.update(homed=1)
                    elif int(c["joint_time_count"]) != STOP_TICKS:
                        fields.update(encoder_pos=np.asarray(c["encoder_pos"]))
                    fields.update(cmd_id=cid, busy=0, cmd_result=CMD_OK)
                st.update(**fields)
        finally:
            st.close()
            cmd.close()

    def __enter__(self) -> "FakeAgent":
        self.th.start()
        return self

    def __exit__(self, *exc) -> None:
        self.done.set()
        self.th.join()


@needs_rclpy
def test_home_then_a_trajectory_carried_out_to_done(db_cell, domain):
    """With an agent that answers (a thread of the test): /arm1/home runs droid-home's routine to
    "done", then a three-point trajectory becomes three joint moves, in order, each with its
    segment's ticks, and the status topic says "done"."""
    from droid.brain.db import arm_command
    from droid.brain.db.layouts import HOME_MODE

    cell, path = db_cell
    write_statuses(cell, homed=0)
    gearing = load_robot("reis_v15").gearing
    q_now = gearing.counts_to_joints(np.asarray(COUNTS, float))
    pts = [(q_now + [2.0, 0, 0, 0, 0, 0], 1.0), (q_now + [4.0, -2.0, 0, 0, 0, 0], 2.0), (q_now + [4.0, -2.0, 3.0, 0, 0, 0], 3.5)]
    spec = {"joint_names": JOINTS, "points": [[np.radians(q).tolist(), t] for q, t in pts]}
    with FakeAgent(cell) as agent, reaped(start_node(path, domain, "--allow-commands")) as proc:
        home = probe(domain, "trigger", "/arm1/home", str(DISCOVERY_S))
        assert home["success"] is True, home
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not any(c["cmd_mode"] == int(HOME_MODE) for c in agent.taken):
            time.sleep(0.05)
        time.sleep(1.0)  # droid-home's wait for HOMED, then NORMAL
        res = probe(domain, "trajectory", "arm1", str(DISCOVERY_S + 30), json.dumps(spec))
        code, err = stop_node(proc)
    assert code == 0, err
    st = [s for s in res["status"] if s["command"] == "trajectory"]
    assert [s["state"] for s in st] == ["started", "done"], res
    moves = [c for c in agent.taken if c["cmd_mode"] != int(HOME_MODE)]
    assert len(moves) == 3, agent.taken
    t_prev = 0.0
    for c, (q, t) in zip(moves, pts):
        assert c["encoder_pos"] == np.rint(gearing.joints_to_counts(q)).astype(int).tolist()
        assert c["joint_time_count"] == arm_command.ticks_for(t - t_prev, cell.heartbeat_hz)
        t_prev = t


def test_droid_ros2_reads_the_brain_and_commands_through_the_tasks_only():
    """docs/design.md §7 and §12: droid-ros2 reads the Brain's databases as the observers do and commands
    only through the tasks' code (BrainArm): never a device, an agent or the simulator.  Only the
    command path (ArmCommands, through droid.tasks) opens a Command record."""
    import ast

    from tests.layering import DROID, droid_imports, within

    may = ("droid.brain", "droid.kinematics", "droid.cli", "droid.observe", "droid.tasks", "droid.ros2")
    for path in (DROID / "ros2").rglob("*.py"):
        for n in droid_imports(path):
            assert within(n, may), (path, n)
    for path in (DROID / "ros2").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", "")) == "open_brain":
                area = node.args[2] if len(node.args) > 2 else None
                assert isinstance(area, ast.Constant) and area.value == "status", (path, node.lineno)
