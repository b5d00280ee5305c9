"""droid-ros2: the cell as a ROS 2 node, an observer and (with --allow-commands) a task (issue 42; docs/ros2.md).

``droid-ros2 [--cell FILE] [--domain N] [--subnet] [--allow-commands] [--seconds S]``
``droid-ros2 --setup DIR [--cell FILE]``: the arms' URDFs into DIR and the shell lines that give a
ROS 2 machine the cell's /tf (:func:`setup_lines`); needs no ROS.

On every heartbeat tick it reads the Brain's Status databases (read-only, like droid-web and
droid-foxglove; docs/design.md §10 "Observers never command") and publishes with rclpy:

* ``/<arm>/joint_states`` sensor_msgs/JointState: ``joint_1`` .. ``joint_6`` (the names ``droid-kin
  urdf`` writes) [rad], the Status ``encoder_pos`` through the robot's gearing; the stamp is the
  wall-clock time of the Status refresh (its ``updated_ns``);
* ``/<arm>/tool_pose`` geometry_msgs/PoseStamped: the Status pose (the wrist-centre point, the
  URDF's ``tool0``) in ``world`` [m]; ``/tcp_pose``: the tool point of the cell's tool arm;
* ``/<ft>/wrench`` geometry_msgs/WrenchStamped: a force/torque sensor's fresh valid reading, in
  the tool arm's ``<arm>/tool0`` axes (as droid-web draws it);
* ``/<sensor>/reading`` geometry_msgs/PoseStamped: a line-laser sensor's new valid reading (x depth,
  y lateral, z, R the roll) in its frame -- the message the ROS 2 bag export uses (docs/ros2.md
  says why not LaserScan or Range);

once a second ``/diagnostics`` diagnostic_msgs/DiagnosticArray (every subunit's Status health:
fresh or stale, faults, homed; every program's state, live and LAGGING), twice a second
``/cell_markers`` visualization_msgs/MarkerArray (the bodies, the workpiece, the seam map, the
laser plane), and once, latched (transient local, as robot_state_publisher does),
``/<arm>/robot_description`` std_msgs/String: the arm's URDF exactly as ``droid-kin urdf --cell FILE
--subunit ARM`` prints it.  No /tf: tf2_msgs has no wheel on PyPI (docs/ros2.md: run
robot_state_publisher on these topics).

With ``--allow-commands`` only (else no such topic or service exists):

* ``/<arm>/joint_trajectory`` trajectory_msgs/JointTrajectory (joint_trajectory_controller's topic):
  checked whole before anything is written (:mod:`droid.ros2.trajectory`: droid-move's limits, speed
  and readiness rules), then one droid-move joint move per segment in its time, through the
  Brain's Command (:meth:`droid.tasks.arm.BrainArm.move`);
* ``/<arm>/home`` and ``/<arm>/stop`` std_srvs/Trigger (droid-home's routine; a stop written over the
  move in progress);
* ``/<arm>/command_status`` std_msgs/String, JSON, latched: each command's result
  (``refused`` with the reason, ``started``, ``done``, ``failed``, ``stopped``).

Loopback only unless ``--subnet`` (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST); the domain id is
``--domain``, else the cell file's ``[ros2] domain_id``, else ``$ROS_DOMAIN_ID``, else 0
(:func:`domain_of`).

Exit: 0 on SIGINT/SIGTERM or after ``--seconds``; 1 cell not up; 2 bad arguments, the extra
not installed (one line naming ``pip install 'droid[ros2]'``).
"""
from __future__ import annotations

import json
import math
import os
import sys
import threading
import time

import numpy as np

from droid.cli import BadInput, DroidError, bounded_int, duration_s, run

PROG = "droid-ros2"
DIAG_PERIOD_S = 1.0  # /diagnostics once a second (the diagnostic_aggregator's rate)
MARKER_PERIOD_S = 0.5  # /cell_markers twice a second
M_PER_MM = 1e-3
WORLD = "world"
TICK_WAIT_PERIODS = 1.5  # no heartbeat tick within this many periods: publish on our own clock
#: the scene (link bodies, seam map, laser line: droid.observe.scene.SceneBuilder) every 4th tick, 15 Hz
#: at 60 Hz -- as droid-foxglove's 30 Hz, the seam map keeps a point a mm -- while someone watches the
#: markers or the lead sensor reads (the seam map grows); the rest every tick, each topic only while
#: someone subscribes to it
SCENE_EVERY_TICKS = 4
SEAM_EVERY_TICKS = 8  # ... while only the seam map grows (no one watches): 7.5 Hz, a point each 2 mm at 16 mm/s
#: the Status fields droid-ros2 reads (arms, line-laser sensors, force/torque sensors, joysticks)
FIELDS = frozenset({"x", "y", "z", "R", "encoder_pos", "encoder_cmd", "busy", "homed", "tick", "updated_ns", "stale",
                    "fault", "cmd_mode", "cmd_id", "cmd_result", "valid", "force_N", "torque_Nm", "saturated"})


def domain_of(args, cell=None, environ=os.environ) -> int:
    """``--domain``, else the cell file's ``[ros2] domain_id``, else ``$ROS_DOMAIN_ID``, else 0."""
    if args.domain is not None:
        return args.domain
    if cell is not None and getattr(cell, "ros2_domain", None) is not None:
        return int(cell.ros2_domain)
    v = environ.get("ROS_DOMAIN_ID", "").strip()
    if v:
        try:
            return int(v)
        except ValueError:
            raise BadInput(f"ROS_DOMAIN_ID={v!r} is not a number: give --domain N") from None
    return 0


# ------------------------------------------------------------------ the cell's arms as URDF


def arm_urdfs(cell) -> dict[str, str]:
    """Each arm's URDF as ``droid-kin urdf --cell FILE --subunit ARM`` prints it (tool/sensor mounts)."""
    from droid.cli import read_toml
    from droid.kinematics import load_robot
    from droid.kinematics.cli import cell_mounts
    from droid.kinematics.urdf import robot_urdf

    raw = read_toml(cell.path, "cell file")
    out = {}
    for s in cell.subunits.values():
        if not s.is_arm or not s.robot:
            continue
        _, mounts = cell_mounts(raw, s.name, f"cell {cell.path}")
        out[s.name] = robot_urdf(load_robot(s.robot), tool=mounts.get("tool"), sensor=mounts.get("sensor"))
    return out


def num(v: float) -> str:
    """A number for a command line: 9 significant digits, rounding noise (below 1e-12) and -0 as 0."""
    v = 0.0 if abs(v) < 1e-12 else float(v)
    return f"{v:.9g}"


def setup_lines(cell) -> list[str]:
    """Shell lines for a ROS 2 machine that put the cell's arms into /tf (tf2_msgs has no wheel, so
    droid-ros2 publishes no /tf): per arm a static_transform_publisher of ``world`` -> ``<arm>/base_link``
    (the cell file's base) and a robot_state_publisher in the arm's namespace on its joint states,
    with the URDF ``droid-kin urdf`` writes (``<arm>.urdf``, written next to the lines)."""
    from droid.kinematics.transforms import pose_to_T

    lines = [f"# the cell {cell.name}: run on the ROS 2 machine (same ROS_DOMAIN_ID; see docs/ros2.md)"]
    for s in cell.subunits.values():
        if not s.is_arm or not s.robot:
            continue
        T = pose_to_T(*s.base)
        qx, qy, qz, qw = (num(v) for v in quat_xyzw(T[:3, :3]))
        x, y, z = (num(float(T[i, 3]) * M_PER_MM) for i in range(3))
        lines += [f"# {s.name} ({s.robot}): its URDF in {s.name}.urdf (droid-kin urdf --cell FILE --subunit {s.name})",
                  f"ros2 run tf2_ros static_transform_publisher --x {x} --y {y} --z {z} --qx {qx} "
                  f"--qy {qy} --qz {qz} --qw {qw} --frame-id {WORLD} --child-frame-id {s.name}/base_link &",
                  f"ros2 run robot_state_publisher robot_state_publisher --ros-args -r __ns:=/{s.name} "
                  f"-p frame_prefix:={s.name}/ -p robot_description:=\"$(cat {s.name}.urdf)\" &"]
    return lines


# ------------------------------------------------------------------ Status -> ROS messages


def quat_xyzw(R) -> tuple[float, float, float, float]:
    from droid.observe.scene import quat

    q = quat(np.asarray(R, float))
    return q["x"], q["y"], q["z"], q["w"]


class Feed:
    """One tick of Status dicts -> rclpy messages.  ``meta``: :func:`droid.observe.mcapfile.cell_meta`."""

    def __init__(self, cell, meta: dict) -> None:
        from builtin_interfaces.msg import Time
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from sensor_msgs.msg import JointState
        from visualization_msgs.msg import Marker, MarkerArray

        from droid.kinematics import load_robot
        from droid.observe.scene import SceneBuilder

        self.M = dict(Time=Time, DiagnosticArray=DiagnosticArray, DiagnosticStatus=DiagnosticStatus,
                      KeyValue=KeyValue, PoseStamped=PoseStamped, WrenchStamped=WrenchStamped,
                      JointState=JointState, Marker=Marker, MarkerArray=MarkerArray)
        self.cell = cell
        self.meta = meta
        self.scene = SceneBuilder(meta.get("subunits", []), meta.get("scene", {}))
        g = meta.get("scene") or {}
        self.tool_robot = g.get("tool_robot")
        self.lead = g.get("sensor")
        self.arms: dict[str, object] = {}  # arm -> gearing
        self.fts: list[str] = []
        self.lasers: list[str] = []
        for s in meta.get("subunits", []):
            lay = ((s.get("areas") or {}).get("status") or {}).get("layout")
            if lay == "arm_status" and s.get("robot"):
                self.arms[s["name"]] = load_robot(s["robot"]).gearing
            elif lay == "ft6_status":
                self.fts.append(s["name"])
            elif lay == "sensor_status":
                self.lasers.append(s["name"])
        self.mono_to_wall_ns = time.time_ns() - time.monotonic_ns()
        self._last_reading: dict[str, tuple[int, int]] = {}
        self.names = [f"joint_{i}" for i in range(1, 7)]

    def stamp(self, mono_ns: int | None = None):
        t = time.time_ns() if not mono_ns else int(mono_ns) + self.mono_to_wall_ns
        t = max(0, t)
        return self.M["Time"](sec=t // 1_000_000_000, nanosec=t % 1_000_000_000)

    def _pose_msg(self, T, stamp, frame: str):
        m = self.M["PoseStamped"]()
        m.header.stamp, m.header.frame_id = stamp, frame
        p = m.pose.position
        p.x, p.y, p.z = (float(T[i, 3]) * M_PER_MM for i in range(3))
        o = m.pose.orientation
        o.x, o.y, o.z, o.w = quat_xyzw(T[:3, :3])
        return m

    def tick(self, st: dict[str, dict], scene: bool = True, wanted=None) -> tuple[list[tuple[str, object]], dict | None]:
        """``([(topic, message)], geometry)`` of one snapshot; ``geometry`` (:meth:`SceneBuilder.step`:
        bodies, seam map, laser line; None without ``scene``) is what the markers draw.  ``wanted(topic)``
        false: that topic's message is not built (no one subscribes to it)."""
        from droid.observe.scene import status_T

        want = wanted or (lambda topic: True)
        out: list[tuple[str, object]] = []
        geo = self.scene.step(st) if scene else None
        wcp: dict[str, np.ndarray] = {}
        for arm, gearing in self.arms.items():
            d = st.get(arm)
            if d is None:
                continue
            stamp = self.stamp(d.get("updated_ns"))
            if want(f"/{arm}/joint_states"):
                js = self.M["JointState"]()
                js.header.stamp = stamp
                js.name = self.names
                q = gearing.counts_to_joints(np.asarray(d["encoder_pos"], float))
                js.position = [math.radians(float(v)) for v in q]
                out.append((f"/{arm}/joint_states", js))
            wcp[arm] = T = status_T(d)
            if want(f"/{arm}/tool_pose"):
                out.append((f"/{arm}/tool_pose", self._pose_msg(T, stamp, WORLD)))
        if self.tool_robot in wcp and self.scene.T_wcp_tool is not None and want("/tcp_pose"):
            d = st.get(self.tool_robot) or {}
            out.append(("/tcp_pose", self._pose_msg(wcp[self.tool_robot] @ self.scene.T_wcp_tool,
                                                    self.stamp(d.get("updated_ns")), WORLD)))
        for ft in self.fts:
            d = st.get(ft)
            if d is None or d.get("stale") or not d.get("valid") or not want(f"/{ft}/wrench"):
                continue
            w = self.M["WrenchStamped"]()
            w.header.stamp = self.stamp(d.get("updated_ns"))
            w.header.frame_id = f"{self.tool_robot}/tool0" if self.tool_robot else ft
            f, t = np.asarray(d["force_N"], float), np.asarray(d["torque_Nm"], float)
            w.wrench.force.x, w.wrench.force.y, w.wrench.force.z = (float(v) for v in f)
            w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z = (float(v) for v in t)
            out.append((f"/{ft}/wrench", w))
        for s in self.lasers:
            d = st.get(s)
            if d is None or d.get("stale") or d.get("homed"):  # a line laser's homed = 1: no valid reading
                continue
            key = (int(d.get("tick", 0)), int(d.get("updated_ns", 0)))
            if self._last_reading.get(s) == key:
                continue
            self._last_reading[s] = key
            if want(f"/{s}/reading"):
                out.append((f"/{s}/reading", self._pose_msg(status_T(d), self.stamp(d.get("updated_ns")),
                                                            "sensor" if s == self.lead else s)))
        return out, geo

    # -- diagnostics ---------------------------------------------------------------
    def diagnostics(self, st: dict[str, dict], health: dict | None):
        from droid.brain.db.layouts import FAULTS_CANNOT_MOVE, fault_names

        DS, KV = self.M["DiagnosticStatus"], self.M["KeyValue"]
        arr = self.M["DiagnosticArray"]()
        arr.header.stamp = self.stamp()
        for name, d in st.items():
            s = DS()
            s.name, s.hardware_id = f"droid/{name}", name
            faults = int(d.get("fault", 0))
            stale = bool(d.get("stale", 0))
            if stale:
                s.level, s.message = DS.STALE, "stale: its agent does not answer"
            elif faults & FAULTS_CANNOT_MOVE:
                s.level, s.message = DS.ERROR, f"faults: {', '.join(fault_names(faults))}"
            elif faults:
                s.level, s.message = DS.WARN, f"faults: {', '.join(fault_names(faults))}"
            else:
                s.level, s.message = DS.OK, "live"
            vals = {"tick": d.get("tick"), "stale": int(stale), "faults": ",".join(fault_names(faults)) or "none"}
            for k in ("homed", "busy", "cmd_id", "cmd_result", "valid"):
                if k in d:
                    vals[k] = d[k]
            s.values = [KV(key=k, value=str(v)) for k, v in vals.items()]
            arr.status.append(s)
        for row in (health or {}).get("programs", []):
            s = DS()
            s.name, s.hardware_id = f"droid/program/{row.get('name')}", str(row.get("host", ""))
            if not row.get("live"):
                s.level, s.message = DS.ERROR, f"not live ({row.get('state')})"
            elif row.get("lagging"):
                s.level, s.message = DS.WARN, f"LAGGING: missed {row.get('missed_pct')} % of its ticks"
            else:
                s.level, s.message = DS.OK, "live"
            s.values = [KV(key=k, value=str(row.get(k))) for k in
                        ("state", "live", "lagging", "missed_pct", "lateness_max_ms", "pid")]
            arr.status.append(s)
        return arr

    # -- markers --------------------------------------------------------------------
    def markers(self, geo: dict):
        from droid.observe.scene import WORKPIECE_BOX_MM

        Marker, MA = self.M["Marker"], self.M["MarkerArray"]
        from geometry_msgs.msg import Point
        from std_msgs.msg import ColorRGBA

        stamp = self.stamp()
        arr = MA()

        def mk(ns: str, i: int, typ: int, rgba) -> object:
            m = Marker()
            m.header.stamp, m.header.frame_id = stamp, WORLD
            m.ns, m.id, m.type, m.action = ns, i, typ, Marker.ADD
            m.color = ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
            m.pose.orientation.w = 1.0
            return m

        def pt(p) -> object:
            return Point(x=float(p[0]) * M_PER_MM, y=float(p[1]) * M_PER_MM, z=float(p[2]) * M_PER_MM)

        for group, caps in geo["bodies"].items():
            for i, c in enumerate(caps):
                a, b, r = np.asarray(c[:3], float), np.asarray(c[3:6], float), float(c[6])
                m = mk(f"bodies/{group}", i, Marker.CYLINDER, (0.55, 0.57, 0.62, 0.6))
                v = b - a
                n = float(np.linalg.norm(v))
                mid = (a + b) / 2
                m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(x) * M_PER_MM for x in mid)
                if n > 1e-9:  # rotate z onto the segment
                    z = v / n
                    ax = np.cross([0.0, 0.0, 1.0], z)
                    s = float(np.linalg.norm(ax))
                    ang = math.atan2(s, float(z[2]))
                    ax = ax / s if s > 1e-12 else np.array([1.0, 0.0, 0.0])
                    m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z = (float(x) * math.sin(ang / 2) for x in ax)
                    m.pose.orientation.w = math.cos(ang / 2)
                m.scale.x = m.scale.y = 2 * r * M_PER_MM
                m.scale.z = max(n, 1e-3) * M_PER_MM
                arr.markers.append(m)
        W = geo["frames"].get("workpiece")
        if W is not None:
            lx, wy, tz = WORKPIECE_BOX_MM
            m = mk("workpiece", 0, Marker.CUBE, (0.6, 0.6, 0.65, 0.8))
            c = W @ np.array([lx / 2, 0.0, -tz / 2, 1.0])
            m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(x) * M_PER_MM for x in c[:3])
            m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = quat_xyzw(W[:3, :3])
            m.scale.x, m.scale.y, m.scale.z = lx * M_PER_MM, wy * M_PER_MM, tz * M_PER_MM
            arr.markers.append(m)
        seam = mk("seam", 0, Marker.LINE_STRIP, (1.0, 0.8, 0.0, 1.0))
        seam.scale.x = 0.002
        seam.points = [pt(p) for p in geo["seam"]]
        if not seam.points:
            seam.action = Marker.DELETE
        arr.markers.append(seam)
        laser = mk("laser_plane", 0, Marker.TRIANGLE_LIST, (1.0, 0.0, 0.0, 0.35))
        laser.scale.x = laser.scale.y = laser.scale.z = 1.0
        if geo["laser"] and geo["laser_src"]:
            laser.points = [pt(geo["laser_src"]), pt(geo["laser"][0]), pt(geo["laser"][1])]
        else:
            laser.action = Marker.DELETE
        arr.markers.append(laser)
        return arr


# ------------------------------------------------------------------ commands (--allow-commands)


class ArmCommands:
    """The trajectory topic and the home/stop services of one arm, through droid-move's and
    droid-home's code (:class:`droid.tasks.arm.BrainArm`).  One command at a time, in a thread."""

    def __init__(self, node, cell, name: str, say) -> None:
        from std_msgs.msg import String
        from std_srvs.srv import Trigger
        from trajectory_msgs.msg import JointTrajectory
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        from droid.tasks.arm import BrainArm

        self.name = name
        self.say = say
        self.arm = BrainArm(cell, name).connect()  # RuntimeFailure (exit 1) if the cell is not up
        self.String = String
        latched = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub = node.create_publisher(String, f"/{name}/command_status", latched)
        self.subs = [node.create_subscription(JointTrajectory, f"/{name}/joint_trajectory", self.on_trajectory, 10)]
        self.srvs = [node.create_service(Trigger, f"/{name}/home", self.on_home),
                     node.create_service(Trigger, f"/{name}/stop", self.on_stop)]
        self.lock = threading.Lock()
        self.worker: threading.Thread | None = None
        self.stop_evt = threading.Event()
        self.seq = 0
        self.topics = [f"/{name}/joint_trajectory", f"/{name}/home", f"/{name}/stop", f"/{name}/command_status"]

    def report(self, command: str, state: str, reason: str = "", **extra) -> dict:
        d = {"arm": self.name, "command": command, "seq": self.seq, "state": state, "reason": reason, **extra}
        self.pub.publish(self.String(data=json.dumps(d)))
        return d

    def busy(self) -> bool:
        return self.worker is not None and self.worker.is_alive()

    def on_trajectory(self, msg) -> None:
        from droid.ros2.trajectory import duration_s as dur, plan
        from droid.tasks.move import check_ready

        with self.lock:
            self.seq += 1
            points = [(list(p.positions), dur(p.time_from_start.sec, p.time_from_start.nanosec)) for p in msg.points]
            try:
                if self.busy():
                    raise BadInput(f"busy: a command of {self.name} is running (call /{self.name}/stop first)")
                rec = check_ready(self.arm)
                legs = plan(self.arm, list(msg.joint_names), points, self.arm.joints_deg(rec))
            except DroidError as exc:
                self.say(f"{self.name}: trajectory {self.seq} refused: {exc}")
                self.report("trajectory", "refused", str(exc), points=len(points))
                return
            self.stop_evt.clear()
            self.report("trajectory", "started", points=len(legs), seconds=legs[-1].t_end_s)
            self.worker = threading.Thread(target=self._run_legs, args=(self.seq, legs), daemon=True)
            self.worker.start()

    def _carry_out(self, what: str, seq: int, work, failed_as: str) -> None:
        """Run a started command's ``work`` (a worker thread's body) and report how it ended on the
        status topic: ``stopped`` (/stop), ``failed`` (said in the log as ``failed_as failed``) or
        ``done`` with whatever ``work`` returns."""
        from droid.tasks.arm import Interrupted

        try:
            extra = work() or {}
        except Interrupted as exc:
            self.report(what, "stopped", str(exc), **{what: seq})
            return
        except DroidError as exc:
            self.say(f"{self.name}: {failed_as} failed: {exc}")
            self.report(what, "failed", str(exc), **{what: seq})
            return
        self.report(what, "done", **{what: seq}, **extra)

    def _run_legs(self, seq: int, legs) -> None:
        def legs_moved() -> dict:
            t0 = time.monotonic()
            for i, leg in enumerate(legs):
                self.arm.move("joint", leg.counts, leg.seconds, arrive=(i == len(legs) - 1),
                              interrupted=self.stop_evt.is_set, say=lambda line: self.say(f"{self.name}: {line}"))
            return {"seconds": round(time.monotonic() - t0, 3)}

        self._carry_out("trajectory", seq, legs_moved, f"trajectory {seq}")

    def on_home(self, request, response):
        from droid.tasks.home import home

        with self.lock:
            self.seq += 1
            if self.busy():
                response.success, response.message = False, f"busy: a command of {self.name} is running"
                self.report("home", "refused", response.message)
                return response
            seq = self.seq

            def homed() -> None:
                home(self.arm, interrupted=self.stop_evt.is_set)

            self.stop_evt.clear()
            self.report("home", "started")
            self.worker = threading.Thread(target=self._carry_out, args=("home", seq, homed, "home"), daemon=True)
            self.worker.start()
        response.success, response.message = True, f"homing {self.name}: the result on /{self.name}/command_status"
        return response

    def on_stop(self, request, response):
        from droid.brain.db import arm_command

        with self.lock:
            self.seq += 1
            running = self.busy()
            self.stop_evt.set()  # a trajectory or homing in progress gives up (BrainArm.give_up: a stop of its own)
            try:
                arm_command.stop(self.arm.command)  # at once, whatever the worker is waiting on (one lock: databases.write_command)
            except DroidError as exc:
                response.success, response.message = False, str(exc)
                self.report("stop", "failed", str(exc))
                return response
            if running:
                self.worker.join(1.0)
            self.report("stop", "done")
        response.success, response.message = True, f"{self.name} stopped where it stood"
        return response

    def close(self) -> None:
        if self.busy():
            self.stop_evt.set()
            self.worker.join(3.0)
        self.arm.close()


# ------------------------------------------------------------------ the program


class StatusReader:
    """The Status record of every subunit of the cell, read-only (what the publishers need; the Command
    records are opened only by :class:`ArmCommands`)."""

    def __init__(self, cell) -> None:
        from droid.brain.db.databases import brain_layouts, open_brain

        self.dbs = []
        try:
            for sub in cell.subunits.values():
                if "status" in brain_layouts(sub):
                    self.dbs.append((sub.name, open_brain(cell, sub, "status")))
        except BaseException:
            self.close()
            raise

    def read(self) -> dict[str, dict]:
        """``{subunit: {field: value}}``: the fields the publishers and the scene read (:data:`FIELDS`),
        as Python values (a record's arrays as lists), of a consistent copy of each record."""
        out = {}
        for name, db in self.dbs:
            rec = db.read()
            names = rec.dtype.names
            vals = rec.tolist()
            out[name] = {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                         for k, v in zip(names, vals) if k in FIELDS}
        return out

    def close(self) -> None:
        for _, db in self.dbs:
            db.close()
        self.dbs = []


class Ros2Node:
    """The node: publishers (+ commands), paced by the heartbeat (:meth:`run`)."""

    def __init__(self, cell, allow_commands: bool, say) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String
        from visualization_msgs.msg import MarkerArray

        from droid.observe.mcapfile import cell_meta
        from droid.observe.scene import scene_meta

        self.cell = cell
        self.say = say
        self.meta = cell_meta(cell, "live", scene_meta(cell))
        self.urdfs = arm_urdfs(cell)
        self.sampler = StatusReader(cell)  # RuntimeFailure (exit 1) if the cell is not up
        self.feed = Feed(cell, self.meta)
        self.node = rclpy.create_node("droid", namespace="/", context=None)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pubs: dict[str, object] = {}
        for arm in self.feed.arms:
            self.pubs[f"/{arm}/joint_states"] = self.node.create_publisher(JointState, f"/{arm}/joint_states", qos)
            self.pubs[f"/{arm}/tool_pose"] = self.node.create_publisher(PoseStamped, f"/{arm}/tool_pose", qos)
        if self.feed.tool_robot in self.feed.arms and self.feed.scene.T_wcp_tool is not None:
            self.pubs["/tcp_pose"] = self.node.create_publisher(PoseStamped, "/tcp_pose", qos)
        for ft in self.feed.fts:
            self.pubs[f"/{ft}/wrench"] = self.node.create_publisher(WrenchStamped, f"/{ft}/wrench", qos)
        for s in self.feed.lasers:
            self.pubs[f"/{s}/reading"] = self.node.create_publisher(PoseStamped, f"/{s}/reading", qos)
        self.diag_pub = self.node.create_publisher(DiagnosticArray, "/diagnostics", qos)
        self.marker_pub = self.node.create_publisher(MarkerArray, "/cell_markers", qos)
        self.desc_pubs = {}
        for arm, text in self.urdfs.items():
            p = self.node.create_publisher(String, f"/{arm}/robot_description", latched)
            p.publish(String(data=text))
            self.desc_pubs[arm] = p
        self.commands: dict[str, ArmCommands] = {}
        if allow_commands:
            for arm in self.feed.arms:
                self.commands[arm] = ArmCommands(self.node, cell, arm, say)
        self.published = 0
        self.own_clock_ticks = 0
        self._diag_t = self._marker_t = -math.inf
        self._health: dict = {}
        self._n = 0
        self._geo: dict | None = None

    def _listened(self, topic: str) -> bool:
        """Whether anyone subscribes to ``topic`` (a message no one takes is not built)."""
        return self.pubs[topic].get_subscription_count() > 0

    def topics(self) -> list[str]:
        t = list(self.pubs) + ["/diagnostics", "/cell_markers"] + [f"/{a}/robot_description" for a in self.desc_pubs]
        for c in self.commands.values():
            t += c.topics
        return t

    def once(self, heard_tick: bool) -> None:
        from droid.observe.sampler import health

        try:
            st = self.sampler.read()
        except DroidError as exc:  # a database held too long: skip this tick
            self.say(f"read: {exc}")
            return
        self._n += 1
        lead = st.get(self.feed.lead) or {}
        seam = bool(lead) and not lead.get("stale") and not lead.get("homed")  # the seam map grows
        watched = self.marker_pub.get_subscription_count() > 0
        scene = (self._geo is None or (watched and self._n % SCENE_EVERY_TICKS == 0)
                 or (seam and self._n % SEAM_EVERY_TICKS == 0))
        msgs, geo = self.feed.tick(st, scene=scene, wanted=self._listened)
        self._geo = geo or self._geo
        for topic, m in msgs:
            self.pubs[topic].publish(m)
        self.published += len(msgs)
        now = time.monotonic()
        if now - self._diag_t >= DIAG_PERIOD_S and self.diag_pub.get_subscription_count() > 0:
            self._diag_t = now
            self._health = health(self.cell)
            arr = self.feed.diagnostics(st, self._health)
            if not heard_tick:
                from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

                arr.status.append(DiagnosticStatus(level=DiagnosticStatus.WARN, name="droid/heartbeat",
                                                   message="no heartbeat tick heard: publishing on droid-ros2's own clock",
                                                   values=[KeyValue(key="own_clock_ticks", value=str(self.own_clock_ticks))]))
            self.diag_pub.publish(arr)
            self.published += 1
        if now - self._marker_t >= MARKER_PERIOD_S and self.marker_pub.get_subscription_count() > 0:
            self._marker_t = now
            self.marker_pub.publish(self.feed.markers(self._geo))
            self.published += 1

    def run(self, stop: threading.Event, seconds: float | None) -> None:
        """Publish on every heartbeat tick until ``stop`` (or ``seconds``); without ticks (no
        heartbeat heard for 1.5 periods) on our own clock at the heartbeat rate."""
        import zmq

        from droid.brain.runtime.heartbeat import TickSubscriber

        period = 1.0 / self.cell.heartbeat_hz
        ticks = TickSubscriber(zmq.Context.instance(), self.cell.heartbeat)
        t_end = None if seconds is None else time.monotonic() + seconds
        try:
            heard = True
            nxt = time.monotonic()
            while not stop.is_set() and (t_end is None or time.monotonic() < t_end):
                if heard:
                    t = ticks.wait(TICK_WAIT_PERIODS * period)
                    nxt = time.monotonic()  # no tick: our own clock starts from here
                else:  # our own clock: absolute deadlines a period apart, as the heartbeat keeps them
                    nxt += period
                    now = time.monotonic()
                    if nxt < now - 1.0:
                        nxt = now
                    t = ticks.wait(max(0.0, nxt - now))
                heard = t is not None
                if not heard:
                    self.own_clock_ticks += 1
                self.once(heard)
        finally:
            ticks.close()

    def close(self) -> None:
        for c in self.commands.values():
            c.close()
        self.sampler.close()
        self.node.destroy_node()


@run
def main(argv=None) -> int:
    from droid.brain.runtime.program import open_cell, parser
    from droid.ros2 import env

    ap = parser(PROG, "The cell as a ROS 2 node: joint states, poses, wrenches, readings, diagnostics, markers "
                      "and robot descriptions from the Brain's databases; with --allow-commands trajectories "
                      "and home/stop services through droid-move's checks.")
    ap.add_argument("--domain", type=bounded_int(0, env.DOMAIN_MAX), default=None, metavar="N",
                    help="ROS 2 domain id (default: the cell file's [ros2] domain_id, else $ROS_DOMAIN_ID, else 0)")
    ap.add_argument("--subnet", action="store_true",
                    help="discover peers on the subnet (default: loopback only, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)")
    ap.add_argument("--allow-commands", action="store_true",
                    help="offer /<arm>/joint_trajectory and the /<arm>/home, /<arm>/stop services (default: none exist)")
    ap.add_argument("--seconds", type=duration_s(), default=None, metavar="S", help="stop after S seconds")
    ap.add_argument("--setup", metavar="DIR", default=None,
                    help="write each arm's URDF into DIR and print the shell lines that give a ROS 2 machine the "
                         "cell's /tf (static_transform_publisher, robot_state_publisher); needs no ROS here")
    args = ap.parse_args(argv)
    if args.setup is not None:
        cell = open_cell(args)
        from pathlib import Path

        out = Path(args.setup)
        try:
            out.mkdir(parents=True, exist_ok=True)
            for arm, text in arm_urdfs(cell).items():
                (out / f"{arm}.urdf").write_text(text)
        except OSError as exc:
            raise BadInput(f"--setup {args.setup}: {exc.strerror or exc}") from None
        print("\n".join(setup_lines(cell)))
        return 0
    if not env.installed():
        raise BadInput(f"the ROS 2 Python packages are not installed: {env.EXTRA_HINT}")
    cell = open_cell(args)
    domain = env.check_domain(domain_of(args, cell))
    env.ensure_library_path()
    vals = env.ros_environment(domain, args.subnet)
    rclpy = env.import_rclpy()

    def say(line: str) -> None:
        print(f"{PROG}: {line}", file=sys.stderr, flush=True)

    import signal

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    from rclpy.signals import SignalHandlerOptions

    StatusReader(cell).close()  # the cell is up (else exit 1) before anything of ROS 2 starts
    rclpy.init(domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    node = ex = spin = None
    try:
        node = Ros2Node(cell, args.allow_commands, say)
        from rclpy.executors import MultiThreadedExecutor

        ex = MultiThreadedExecutor(num_threads=2)
        ex.add_node(node.node)
        spin = threading.Thread(target=ex.spin, name="ros2-spin", daemon=True)
        spin.start()
        say(f"cell {cell.name} on ROS 2 domain {domain} ({vals['ROS_AUTOMATIC_DISCOVERY_RANGE']}, "
            f"{vals['RMW_IMPLEMENTATION']}): {len(node.topics())} topics and services; commands "
            f"{'ALLOWED' if args.allow_commands else 'off'}")
        node.run(stop, args.seconds)
        say(f"stopped; {node.published} messages published, {node.own_clock_ticks} ticks on its own clock")
    finally:
        # in this order: no rclpy thread may outlive the context (else the C++ runtime aborts at exit)
        if ex is not None:
            ex.shutdown(timeout_sec=2.0)
        if spin is not None:
            spin.join(2.0)
        if node is not None:
            node.close()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
