"""DROID recordings as ROS 2 bags (issue 29; docs/observe.md "ROS 2 bags"; thesis §3.4, §7.3).

``droid-replay F.mcap --export rosbag2 DIR`` and ``droid-record --format rosbag2
--out DIR`` write a ROS 2 bag with the maintained pure-Python library
``rosbags``: storage ``mcap`` (rosbag2's default storage since Iron, and what
``rosbags`` writes natively), bag version 8, messages CDR-serialized with the
ROS 2 Jazzy type store.  ROS units: metres and radians (DROID's records are in
mm and encoder counts).

:class:`BagConverter` (the core: plain dicts in, rosbags message objects out, no
I/O) turns one tick's Status records into

* ``/<arm>/joint_states`` ``sensor_msgs/msg/JointState``: ``joint_1`` .. ``joint_6``
  (the ROS-Industrial names), position [rad] = the robot's gearing applied to the
  Status ``encoder_pos`` [counts] (:meth:`droid.kinematics.gearing.Gearing.counts_to_joints`,
  §4.1.1.3), velocity [rad/s] the backward difference over the previous recorded tick
  (empty in the first message);
* ``/<arm>/tool_pose`` ``geometry_msgs/msg/PoseStamped``: the Status pose (x, y, z, R,
  Table 3.1: the wrist-centre point) in ``world`` [m];
* ``/tf`` ``tf2_msgs/msg/TFMessage`` every tick: ``<arm>/base`` -> ``<arm>/wcp`` (the Status
  pose); ``/tf_static`` once (transient-local): ``world`` -> ``<arm>/base`` (the cell's base),
  ``<tool arm>/wcp`` -> ``tool`` and ``sensor``, ``<holder>/wcp`` -> ``workpiece``;
* a line-laser sensor's new valid reading (Status x, y, z [mm], R: the roll, Table 3.3)
  as ``geometry_msgs/msg/PoseStamped`` on ``/<sensor>/reading`` in frame ``sensor`` (the
  scene's lead sensor) or ``<subunit>``;
* a joystick's new valid sample as ``sensor_msgs/msg/Joy`` on ``/<joystick>/joy``;
* events (faults, invalid data, program states) as ``rcl_interfaces/msg/Log`` on ``/rosout``.

The database a subunit has decides what it becomes (its Status layout, read from
the recording's metadata), not a list of classes; a layout with no fitting message
is left out and named by :meth:`BagConverter.skipped`.
"""
from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import numpy as np

from droid.cli import BadInput
from droid.kinematics import load_robot
from droid.kinematics.transforms import inv_homo, pose_to_T
from droid.observe.scene import M_PER_MM, status_T

BAG_VERSION = 8  # rosbag2 metadata version 8 (Iron and later read it; rosbags writes 8 or 9)
STORAGE = "mcap"
JOINT_NAMES = tuple(f"joint_{i}" for i in range(1, 7))  # as ROS-Industrial URDFs name them
WORLD = "world"
TOPIC_TF, TOPIC_TF_STATIC, TOPIC_ROSOUT = "/tf", "/tf_static", "/rosout"
T_JOINT_STATE = "sensor_msgs/msg/JointState"
T_TF = "tf2_msgs/msg/TFMessage"
T_POSE = "geometry_msgs/msg/PoseStamped"
T_JOY = "sensor_msgs/msg/Joy"
T_LOG = "rcl_interfaces/msg/Log"
#: foxglove.Log level -> rcl_interfaces/msg/Log level (DEBUG 10, INFO 20, WARN 30, ERROR 40, FATAL 50)
LOG_LEVELS = {1: 10, 2: 20, 3: 30, 4: 40, 5: 50}
#: Status layout -> what it becomes in a bag (anything else: no fitting message, left out)
EXPORTS = {"arm_status": "arm", "sensor_status": "line_laser", "joystick_status": "joystick"}
LOG_TOPIC = "/log"  # the recording's events (foxglove.Log); with the Status topics, all an export decodes


def typestore():
    """The ROS 2 Jazzy type store of ``rosbags`` (message classes and CDR serialization)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


class BagConverter:
    """One tick of Status dicts -> ``[(topic, msgtype, message)]`` (see the module docstring).

    ``meta``: the recording's ``droid`` metadata (subunits with their class, robot, base and
    databases; the scene geometry)."""

    def __init__(self, meta: dict, store=None) -> None:
        self.ts = store or typestore()
        t = self.ts.types
        self._Time, self._Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
        self._JS, self._Pose, self._PS = t[T_JOINT_STATE], t["geometry_msgs/msg/Pose"], t[T_POSE]
        self._Point, self._Quat = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Quaternion"]
        self._TS, self._Tr, self._V3 = (t["geometry_msgs/msg/TransformStamped"], t["geometry_msgs/msg/Transform"],
                                        t["geometry_msgs/msg/Vector3"])
        self._TF, self._Joy, self._Log = t[T_TF], t[T_JOY], t[T_LOG]
        self.arms: dict[str, tuple] = {}  # name -> (gearing or None, base 4x4 [mm], inverse of base)
        self.sensors: dict[str, str] = {}  # name -> frame id of its readings
        self.sticks: list[str] = []
        self._skipped: dict[str, str] = {}
        scene = meta.get("scene") or {}
        for s in meta.get("subunits", []):
            name = s["name"]
            layout = ((s.get("areas") or {}).get("status") or {}).get("layout")
            kind = EXPORTS.get(layout)
            if kind == "arm":
                gearing = None
                try:
                    gearing = load_robot(s["robot"]).gearing if s.get("robot") else None
                except Exception:  # noqa: BLE001 -- an unknown robot file: its pose, no joint states
                    self._skipped[name] = f"robot {s.get('robot')!r} not found: no joint states"
                base = pose_to_T(*[float(v) for v in s.get("base", [0.0] * 6)])
                self.arms[name] = (gearing, base, inv_homo(base))
            elif kind == "line_laser":
                self.sensors[name] = "sensor" if name == scene.get("sensor") else name
            elif kind == "joystick":
                self.sticks.append(name)
            else:
                self._skipped[name] = f"class {s.get('class')} ({layout}): no fitting ROS message"
        self.scene = scene
        self._prev_q: dict[str, tuple[int, np.ndarray]] = {}  # arm -> (t_ns, q [rad])
        self._last_reading: dict[str, tuple] = {}  # sensor/joystick -> (tick, updated_ns) last published
        self._names = list(JOINT_NAMES)
        self._no_effort = np.zeros(0, float)

    def skipped(self) -> dict[str, str]:
        """Subunits (or parts) left out of the bag, with the reason."""
        return dict(self._skipped)

    # -- message pieces --------------------------------------------------------------
    def stamp(self, t_ns: int):
        """builtin_interfaces/Time of ``t_ns`` [ns] (negative times clamp to 0)."""
        t = max(0, int(t_ns))
        return self._Time(sec=t // 1_000_000_000, nanosec=t % 1_000_000_000)

    def header(self, t_ns: int, frame_id: str, stamp=None):
        return self._Header(stamp=stamp or self.stamp(t_ns), frame_id=frame_id)

    def _quat(self, R):
        q = quat_rows(R)
        return self._Quat(x=q[0], y=q[1], z=q[2], w=q[3])

    def pose(self, T) -> object:
        """geometry_msgs/Pose [m] of a 4x4 [mm]."""
        T = np.asarray(T, float)
        return self._Pose(position=self._Point(x=float(T[0, 3]) * M_PER_MM, y=float(T[1, 3]) * M_PER_MM,
                                               z=float(T[2, 3]) * M_PER_MM),
                          orientation=self._quat(T[:3, :3].tolist()))

    def record_pose(self, d: dict) -> object:
        """geometry_msgs/Pose [m] of a record's x, y, z [mm] and R (a Status, Table 3.1/3.3)."""
        return self._Pose(position=self._Point(x=float(d["x"]) * M_PER_MM, y=float(d["y"]) * M_PER_MM,
                                               z=float(d["z"]) * M_PER_MM), orientation=self._quat(d["R"]))

    def transform(self, t_ns: int, parent: str, child: str, T, stamp=None) -> object:
        """geometry_msgs/TransformStamped [m] of a 4x4 [mm] (``child`` in ``parent``)."""
        T = np.asarray(T, float)
        return self._TS(header=self.header(t_ns, parent, stamp), child_frame_id=child,
                        transform=self._Tr(translation=self._V3(x=float(T[0, 3]) * M_PER_MM, y=float(T[1, 3]) * M_PER_MM,
                                                                z=float(T[2, 3]) * M_PER_MM),
                                           rotation=self._quat(T[:3, :3].tolist())))

    # -- messages ---------------------------------------------------------------------
    def static_tf(self, t_ns: int) -> list[tuple[str, str, object]]:
        """``/tf_static``: the cell's fixed frames (arm bases in ``world``, tool/sensor on the wrist,
        the workpiece on the holder), from the recording's metadata."""
        tfs = [self.transform(t_ns, WORLD, f"{name}/base", base) for name, (_, base, _) in self.arms.items()]
        g = self.scene
        for parent_arm, key, child in ((g.get("tool_robot"), "T_wcp_tool", "tool"),
                                       (g.get("tool_robot"), "T_wcp_sensor", "sensor"),
                                       (g.get("holder_robot"), "T_wcp_workpiece", "workpiece")):
            if parent_arm in self.arms and key in g:
                tfs.append(self.transform(t_ns, f"{parent_arm}/wcp", child, np.asarray(g[key], float)))
        return [(TOPIC_TF_STATIC, T_TF, self._TF(transforms=tfs))] if tfs else []

    def joint_state(self, name: str, d: dict, t_ns: int, stamp=None):
        """sensor_msgs/JointState of arm ``name``'s Status dict (position [rad], velocity [rad/s])."""
        gearing = self.arms[name][0]
        q = np.radians(gearing.counts_to_joints(d["encoder_pos"]))
        prev = self._prev_q.get(name)
        self._prev_q[name] = (t_ns, q)
        if prev is not None and t_ns > prev[0]:
            vel = (q - prev[1]) / ((t_ns - prev[0]) * 1e-9)
        else:
            vel = self._no_effort
        return self._JS(header=self.header(t_ns, "", stamp), name=self._names, position=q, velocity=vel,
                        effort=self._no_effort)

    def _fresh(self, name: str, d: dict) -> bool:
        """A new reading: its (tick, updated_ns) differs from the last one published."""
        key = (d.get("tick"), d.get("updated_ns"))
        if self._last_reading.get(name) == key:
            return False
        self._last_reading[name] = key
        return True

    def step(self, t_ns: int, statuses: dict[str, dict]) -> list[tuple[str, str, object]]:
        """The messages of one recorded tick at ``t_ns`` [ns]; ``statuses``: subunit -> Status dict."""
        out = []
        tfs = []
        st = self.stamp(t_ns)
        for name, (gearing, base, base_inv) in self.arms.items():
            d = statuses.get(name)
            if d is None:
                continue
            if gearing is not None:
                out.append((f"/{name}/joint_states", T_JOINT_STATE, self.joint_state(name, d, t_ns, st)))
            out.append((f"/{name}/tool_pose", T_POSE, self._PS(header=self.header(t_ns, WORLD, st),
                                                               pose=self.record_pose(d))))
            tfs.append(self.transform(t_ns, f"{name}/base", f"{name}/wcp", base_inv @ status_T(d), st))
        if tfs:
            out.append((TOPIC_TF, T_TF, self._TF(transforms=tfs)))
        for name, frame in self.sensors.items():
            d = statuses.get(name)
            if d is None or d.get("homed") or d.get("stale") or not self._fresh(name, d):
                continue  # homed = 1: the sensor flags its data invalid (Table 3.3)
            out.append((f"/{name}/reading", T_POSE, self._PS(header=self.header(t_ns, frame, st),
                                                             pose=self.record_pose(d))))
        for name in self.sticks:
            d = statuses.get(name)
            if d is None or not d.get("valid") or d.get("stale") or not self._fresh(name, d):
                continue
            na, nb = int(d.get("n_axes", 0)), int(d.get("n_buttons", 0))
            out.append((f"/{name}/joy", T_JOY, self._Joy(
                header=self.header(t_ns, name, st), axes=np.asarray(d["axes"][:na], np.float32),
                buttons=np.asarray(d["buttons"][:nb], np.int32))))
        return out

    def log(self, t_ns: int, d: dict) -> tuple[str, str, object]:
        """A recorded foxglove.Log (fault, event) as rcl_interfaces/Log on ``/rosout``."""
        return (TOPIC_ROSOUT, T_LOG, self._Log(
            stamp=self.stamp(t_ns),
            level=LOG_LEVELS.get(int(d.get("level", 2)), 20), name=f"droid.{d.get('name') or 'cell'}",
            msg=str(d.get("message", "")), file=str(d.get("file", "")), function="", line=int(d.get("line", 0))))


def quat_rows(R) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a rotation matrix given as 3 rows (plain floats: this runs for
    every pose of every tick, where numpy's per-element indexing costs more than the arithmetic)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = R
    tr = m00 + m11 + m22
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        return (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, 0.25 * s
    if m00 > m11 and m00 > m22:
        s = math.sqrt(1.0 + m00 - m11 - m22) * 2
        return 0.25 * s, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s
    if m11 > m22:
        s = math.sqrt(1.0 + m11 - m00 - m22) * 2
        return (m01 + m10) / s, 0.25 * s, (m12 + m21) / s, (m02 - m20) / s
    s = math.sqrt(1.0 + m22 - m00 - m11) * 2
    return (m02 + m20) / s, (m12 + m21) / s, 0.25 * s, (m10 - m01) / s


class BagWriter:
    """A ROS 2 bag directory being written (rosbags ``Writer``, storage mcap, zstd chunks).

    It writes into ``<dir>.partial-<pid>`` beside ``path`` and renames it at :meth:`close`, so a
    failed export leaves any existing bag as it was; ``force`` replaces an existing bag."""

    def __init__(self, path: str | os.PathLike, *, force: bool = False, store=None, compress: bool = True) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        self.path = Path(path)
        check_bag_dir(self.path, force)
        # the bag is made in a hidden directory beside DIR, under DIR's own name (so its storage file
        # is DIR.mcap, as metadata.yaml names it), and moved into place when finished
        self.tmp_parent = self.path.with_name(f".{self.path.name}.partial-{os.getpid()}")
        if self.tmp_parent.exists():
            shutil.rmtree(self.tmp_parent)
        self.tmp_parent.mkdir()
        self.tmp = self.tmp_parent / self.path.name
        self.ts = store or typestore()
        self.force = force
        try:
            self._w = Writer(self.tmp, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
            if compress:  # mcap storage: zstd-compressed chunks inside the file, as rosbag2's mcap plugin reads
                from rosbags.rosbag2 import CompressionFormat, CompressionMode

                self._w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            self._w.open()
        except BaseException:
            shutil.rmtree(self.tmp_parent, ignore_errors=True)
            raise
        self._conns: dict[str, object] = {}
        self.counts: dict[str, int] = {}
        self.types: dict[str, str] = {}
        self.closed = False

    def _conn(self, topic: str, msgtype: str):
        c = self._conns.get(topic)
        if c is None:
            qos = _latched_qos() if topic == TOPIC_TF_STATIC else ()
            c = self._conns[topic] = self._w.add_connection(topic, msgtype, typestore=self.ts,
                                                            offered_qos_profiles=qos)
            self.counts[topic] = 0
            self.types[topic] = msgtype
        return c

    def write(self, t_ns: int, messages) -> None:
        """``messages``: ``[(topic, msgtype, message)]`` stamped ``t_ns`` [ns] in the bag."""
        for topic, msgtype, msg in messages:
            self._w.write(self._conn(topic, msgtype), max(0, int(t_ns)), self.ts.serialize_cdr(msg, msgtype))
            self.counts[topic] += 1

    def close(self) -> None:
        """Finish the bag and move it to its place (replacing an existing bag with ``force``)."""
        if self.closed:
            return
        self.closed = True
        self._w.close()
        if self.path.exists() or self.path.is_symlink():
            check_bag_dir(self.path, self.force)
            if self.path.is_dir() and not self.path.is_symlink():
                shutil.rmtree(self.path)
            else:
                self.path.unlink()
        os.replace(self.tmp, self.path)
        self.tmp_parent.rmdir()

    def abort(self) -> None:
        """Drop the partial bag (any existing bag at ``path`` is left as it was)."""
        if self.closed:
            return
        self.closed = True
        try:
            self._w.close()
        except Exception:  # noqa: BLE001 -- the bag is being thrown away
            pass
        shutil.rmtree(self.tmp_parent, ignore_errors=True)


def _latched_qos():
    """The QoS tf2's static broadcaster offers: reliable, transient-local, keep-last 1."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime)

    zero = QosTime(sec=0, nsec=0)
    return [Qos(history=QosHistory.KEEP_LAST, depth=1, reliability=QosReliability.RELIABLE,
                durability=QosDurability.TRANSIENT_LOCAL, deadline=zero, lifespan=zero,
                liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=zero,
                avoid_ros_namespace_conventions=False)]


def check_bag_dir(path: Path, force: bool) -> None:
    """BadInput unless a bag may be written at ``path``: its parent exists; it does not exist, or
    ``force`` and it is a ROS 2 bag (has ``metadata.yaml``) or an empty directory -- never another
    directory or file, so a slip of the keyboard does not delete one."""
    parent = path.absolute().parent
    if not parent.is_dir():
        raise BadInput(f"directory of {path} does not exist")
    if not (path.exists() or path.is_symlink()):
        return
    if not force:
        raise BadInput(f"{path} exists: give --force to replace it")
    if path.is_dir() and not path.is_symlink() and ((path / "metadata.yaml").is_file() or not any(path.iterdir())):
        return
    raise BadInput(f"{path} exists and is not a ROS 2 bag (no metadata.yaml): --force replaces only a bag "
                   f"or an empty directory")


def export_rosbag2(mcap_path: str, out_dir: str, *, force: bool = False, t_from: int | None = None,
                   t_to: int | None = None) -> tuple[BagWriter, BagConverter]:
    """Convert a DROID recording into a ROS 2 bag at ``out_dir``, tick by tick (the recording is
    streamed, never held in memory); ``t_from``/``t_to``: heartbeat ticks.  Returns the closed
    writer (``counts``, ``types``) and the converter (``skipped``).  The bag's stamps are the
    recording's tick times (``log_time``: the wall clock live, virtual time in lockstep)."""
    from droid.observe.mcapfile import db_topic, read_meta, stream_ticks

    if os.path.abspath(out_dir) == os.path.abspath(mcap_path):
        raise BadInput("the bag directory must not be the recording")
    inside = os.path.commonpath([os.path.abspath(out_dir), os.path.abspath(mcap_path)])
    if inside == os.path.abspath(out_dir):
        raise BadInput(f"{out_dir} holds the recording {mcap_path}: choose another bag directory")
    meta = read_meta(mcap_path)
    conv = BagConverter(meta)
    status_topics = {s["name"]: db_topic(s["name"], "status") for s in meta.get("subunits", [])}
    topics = set(status_topics.values()) | {LOG_TOPIC}
    w = BagWriter(out_dir, force=force, store=conv.ts)
    try:
        first = True
        for tick, t_ns, frame in stream_ticks(mcap_path, topics):
            if t_from is not None and tick < t_from:
                continue
            if t_to is not None and tick > t_to:
                continue
            if first:
                w.write(t_ns, conv.static_tf(t_ns))
                first = False
            statuses = {name: frame[topic][-1] for name, topic in status_topics.items() if topic in frame}
            w.write(t_ns, conv.step(t_ns, statuses))
            for d in frame.get(LOG_TOPIC, ()):
                w.write(t_ns, [conv.log(t_ns, d)])
        w.close()
    except BaseException:
        w.abort()
        raise
    return w, conv


class BagSink:
    """A :class:`~droid.observe.record.CellRecorder`'s writer that writes a ROS 2 bag directly
    (``droid-record --format rosbag2``): the records of a tick are converted when the next tick
    starts or the sink closes; the Foxglove frames, scene, health and Commands are not written."""

    def __init__(self, path: str | os.PathLike, meta: dict, *, force: bool = False) -> None:
        self.meta = dict(meta)
        self.path = str(path)
        self.conv = BagConverter(self.meta)
        self.bag = BagWriter(path, force=force, store=self.conv.ts)
        self.messages = 0
        self.closed = False
        self._t_ns: int | None = None
        self._statuses: dict[str, dict] = {}
        self._first = True

    def _flush_tick(self) -> None:
        if self._t_ns is None:
            return
        msgs = self.conv.step(self._t_ns, self._statuses)
        if self._first:
            msgs = self.conv.static_tf(self._t_ns) + msgs
            self._first = False
        self.bag.write(self._t_ns, msgs)
        self.messages += len(msgs)
        self._statuses = {}

    def tick(self, tick: int, t_ns: int, missed: int = 0) -> None:
        self._flush_tick()
        self._t_ns = int(t_ns)

    def record(self, subunit: str, area: str, layout, rec, tick: int, t_ns: int) -> dict:
        from droid.observe import schemas

        d = rec if isinstance(rec, dict) else schemas.record_to_dict(rec)
        d["_subunit"] = subunit
        if area == "status":
            self._statuses[subunit] = d
        return d

    def log(self, tick: int, t_ns: int, level: int, message: str, name: str) -> None:
        self.bag.write(t_ns, [self.conv.log(t_ns, {"level": level, "message": message, "name": name})])
        self.messages += 1

    def write(self, topic: str, schema: dict, obj: dict, tick: int, t_ns: int, metadata=None) -> None:
        """Frames, scene and health have no place in the bag (the bag has its own /tf)."""

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._flush_tick()
        except BaseException:
            self.bag.abort()
            raise
        self.bag.close()

    def abort(self) -> None:
        self.closed = True
        self.bag.abort()


def summary_lines(counts: dict[str, int], types: dict[str, str]) -> list[str]:
    """``<topic> <type> <count>`` per topic, sorted by topic (the stdout report)."""
    return [f"{topic} {types[topic]} {counts[topic]}" for topic in sorted(counts)]
