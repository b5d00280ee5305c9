"""A plain rclpy node, no DROID code: what a ROS 2 user's node sees of droid-ros2 (issue 42).

Imports only rclpy and the message packages.  Reads its domain from ROS_DOMAIN_ID and must be run
with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.  Prints one JSON object on stdout.

    plain_probe.py listen OUT.json TIMEOUT_S TOPIC=TYPE ...
        one message of each topic decoded into plain JSON (TYPE: pkg/msg/Name; robot_description
        and command_status are subscribed transient-local, as robot_state_publisher does)
    plain_probe.py graph TIMEOUT_S [TOPIC SETTLE_S]
        the topic and service names with their types, after TIMEOUT_S of discovery; with TOPIC,
        once TOPIC is in the graph (or TIMEOUT_S), then SETTLE_S more for the rest of its node's
        endpoints (a new participant discovers the others' endpoints one by one)
    plain_probe.py trajectory ARM TIMEOUT_S JSON
        publishes JSON (``{"joint_names": [...], "points": [[positions, t_s], ...]}``) once a
        subscriber is matched on /ARM/joint_trajectory, then prints the /ARM/command_status
        messages until one is not "started" (or TIMEOUT_S)
    plain_probe.py trigger SERVICE TIMEOUT_S
        calls a std_srvs/Trigger service
    plain_probe.py stream OUT.json SECONDS TOPIC ...
        every sensor_msgs/JointState of each TOPIC for SECONDS after the first arrives: its arrival
        (CLOCK_REALTIME ns), header stamp (ns) and positions (latency and delivery of bench/bench_ros2.py)
    plain_probe.py floor-pub TOPIC SECONDS RATE_HZ
        publishes sensor_msgs/JointState stamped at publishing, on absolute deadlines: the
        middleware's own floor for the same measure
"""
from __future__ import annotations

import importlib
import json
import math
import sys
import time

import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy


def msg_class(name: str):
    pkg, kind, cls = name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), cls)


def to_plain(m):
    """A message as JSON-able data (rosidl's get_fields_and_field_types walk)."""
    if hasattr(m, "get_fields_and_field_types"):
        return {f: to_plain(getattr(m, f)) for f in m.get_fields_and_field_types()}
    if isinstance(m, (list, tuple)) or type(m).__name__ == "array" or hasattr(m, "tolist"):
        return [to_plain(v) for v in (m.tolist() if hasattr(m, "tolist") else m)]
    if isinstance(m, bytes):  # a rosidl byte (DiagnosticStatus.level) or byte[]
        return m[0] if len(m) == 1 else list(m)
    if isinstance(m, float) and not math.isfinite(m):
        return repr(m)
    return m


def latched_qos(topic: str):
    if topic.endswith("robot_description") or topic.endswith("command_status"):
        return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def spin_until(node, done, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not done() and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)


def listen(out: str, timeout_s: float, wants: list[str]) -> dict:
    node = rclpy.create_node("plain_probe")
    got: dict = {}
    arrived: dict = {}
    subs = []
    for w in wants:
        topic, typ = w.split("=", 1)

        def cb(m, topic=topic):
            if topic not in got:
                got[topic] = to_plain(m)
                arrived[topic] = time.time_ns()
        subs.append(node.create_subscription(msg_class(typ), topic, cb, latched_qos(topic)))
    spin_until(node, lambda: len(got) == len(wants), timeout_s)
    res = {"messages": got, "arrived_ns": arrived, "missing": [w for w in wants if w.split("=")[0] not in got]}
    with open(out, "w") as f:
        json.dump(res, f)
    node.destroy_node()
    return {"missing": res["missing"], "got": sorted(got)}


def graph(timeout_s: float, topic: str | None = None, settle_s: float = 0.0) -> dict:
    node = rclpy.create_node("plain_probe_graph")
    if topic is None:
        spin_until(node, lambda: False, timeout_s)
    else:
        spin_until(node, lambda: topic in dict(node.get_topic_names_and_types()), timeout_s)
        spin_until(node, lambda: False, settle_s)
    res = {"topics": {n: t for n, t in node.get_topic_names_and_types()},
           "services": {n: t for n, t in node.get_service_names_and_types()}}
    node.destroy_node()
    return res


def trajectory(arm: str, timeout_s: float, spec: str) -> dict:
    from builtin_interfaces.msg import Duration
    from std_msgs.msg import String
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    d = json.loads(spec)
    node = rclpy.create_node("plain_probe_traj")
    seen: list = []
    node.create_subscription(String, f"/{arm}/command_status", lambda m: seen.append(json.loads(m.data)),
                             latched_qos("command_status"))
    pub = node.create_publisher(JointTrajectory, f"/{arm}/joint_trajectory", 10)
    spin_until(node, lambda: pub.get_subscription_count() > 0, timeout_s)
    spin_until(node, lambda: False, 0.5)  # the latched history of earlier commands arrives first
    before = len(seen)
    msg = JointTrajectory()
    msg.joint_names = d["joint_names"]
    for positions, t in d["points"]:
        p = JointTrajectoryPoint()
        p.positions = [float(v) for v in positions]
        p.time_from_start = Duration(sec=int(math.floor(t)), nanosec=int(round((t - math.floor(t)) * 1e9)))
        msg.points.append(p)
    pub.publish(msg)
    spin_until(node, lambda: any(s.get("command") == "trajectory" and s.get("state") != "started"
                                 for s in seen[before:]) or (d.get("until_started") and len(seen) > before),
               timeout_s)
    matched = pub.get_subscription_count()
    node.destroy_node()
    return {"status": seen[before:], "matched": matched}


def trigger(service: str, timeout_s: float) -> dict:
    from std_srvs.srv import Trigger

    node = rclpy.create_node("plain_probe_trigger")
    cli = node.create_client(Trigger, service)
    if not cli.wait_for_service(timeout_sec=timeout_s):
        return {"error": "no service"}
    fut = cli.call_async(Trigger.Request())
    spin_until(node, fut.done, timeout_s)
    r = fut.result()
    node.destroy_node()
    return {"success": r.success, "message": r.message} if r is not None else {"error": "no answer"}


def stream(out: str, seconds: float, topics: list[str]) -> dict:
    from sensor_msgs.msg import JointState

    node = rclpy.create_node("plain_probe_stream")
    got: dict = {t: [] for t in topics}

    def cb(m, topic):
        now = time.time_ns()
        got[topic].append([now, m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, list(m.position)])

    subs = [node.create_subscription(JointState, t, lambda m, t=t: cb(m, t), 100) for t in topics]
    spin_until(node, lambda: all(got.values()), 60.0)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    with open(out, "w") as f:
        json.dump(got, f)
    del subs
    node.destroy_node()
    return {t: len(v) for t, v in got.items()}


def floor_pub(topic: str, seconds: float, rate: float) -> dict:
    from sensor_msgs.msg import JointState

    node = rclpy.create_node("plain_probe_floor")
    pub = node.create_publisher(JointState, topic, 100)
    spin_until(node, lambda: pub.get_subscription_count() > 0, 60.0)
    period, n = 1.0 / rate, 0
    nxt = time.monotonic()
    end = nxt + seconds
    while time.monotonic() < end:
        nxt += period
        try:
            time.sleep(max(0.0, nxt - time.monotonic()))
        except KeyboardInterrupt:  # the bench stops it with SIGINT
            break
        m = JointState()
        t = time.time_ns()
        m.header.stamp.sec, m.header.stamp.nanosec = t // 1_000_000_000, t % 1_000_000_000
        m.name = [f"joint_{i}" for i in range(1, 7)]
        m.position = [0.0] * 6
        pub.publish(m)
        n += 1
    node.destroy_node()
    return {"published": n}


def main() -> int:
    cmd, *rest = sys.argv[1:]
    rclpy.init()
    try:
        if cmd == "listen":
            res = listen(rest[0], float(rest[1]), rest[2:])
        elif cmd == "graph":
            res = graph(float(rest[0]), *(rest[1:2]), *[float(v) for v in rest[2:3]])
        elif cmd == "trajectory":
            res = trajectory(rest[0], float(rest[1]), rest[2])
        elif cmd == "trigger":
            res = trigger(rest[0], float(rest[1]))
        elif cmd == "stream":
            res = stream(rest[0], float(rest[1]), rest[2:])
        elif cmd == "floor-pub":
            res = floor_pub(rest[0], float(rest[1]), float(rest[2]))
        else:
            raise SystemExit(f"unknown command {cmd}")
    finally:
        rclpy.try_shutdown()
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
