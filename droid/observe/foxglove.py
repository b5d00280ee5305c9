"""droid-foxglove: the live cell (or a recording) on a Foxglove WebSocket (thesis §3.4, §7.3; docs/observe.md).

``droid-foxglove [--cell FILE] [--port 8765] [--host 127.0.0.1] [--token TOKEN] [--rate HZ] [--file F.mcap]``

Serves the cell to the Foxglove app or Lichtblick ("Open connection",
``ws://127.0.0.1:8765``) with the Foxglove SDK's WebSocket server (subprotocol
``foxglove.sdk.v1``: the Foxglove WebSocket protocol ``foxglove.websocket.v1`` renamed;
PyPI ``foxglove-sdk``, the optional extra ``droid[foxglove]``).  Every ``--rate`` period (30 Hz by default) it publishes:

* ``/tf`` -- foxglove.FrameTransforms: ``world`` -> ``<arm>/base``, ``<arm>/wcp``
  (the Status pose), ``tool``, ``sensor``, ``workpiece`` (as the recordings' ``/tf``),
  and per arm the URDF's links ``<arm>/base_link`` .. ``<arm>/link_6``, ``<arm>/flange``,
  ``<arm>/tool0`` from its joint angles (the URDF of :func:`droid.kinematics.urdf.robot_urdf`);
* ``/<arm>/joint_states`` -- foxglove.JointStates: ``joint_1`` .. ``joint_6`` [rad], the
  Status encoder counts through the robot's gearing (DROID's joint zero and signs);
* ``/tool_pose`` -- foxglove.PoseInFrame: the tool point's pose in ``world``;
* ``/laser`` -- foxglove.SceneUpdate: the laser line across the lead sensor's frame;
* ``/scene`` -- foxglove.SceneUpdate, twice a second: the workpiece plate and the seam map;
* ``/<subunit>/status`` -- the subunit's Status record as JSON with its JSON Schema
  (``droid.<layout>``, as in a recording), for every subunit;
* ``/guard/status`` -- the collision guard's Status record (``droid.guard_status``), where the
  cell (or the recording) has one; ``/guard`` -- what the page shows of it (``droid.guard_view``:
  state ``off`` | ``clear`` | ``slowing`` | ``stopped`` -- ``off`` with why where the cell has no
  guard, ``run = false`` or no pass yet -- the least distance [mm], the closest pair, the override
  per arm); ``/guard/closest`` -- foxglove.SceneUpdate: the line between the closest pair's two
  closest points, green / amber / red by state, empty when off (docs/guard.md §7a).

Lengths are in metres, as Foxglove expects (everything else in DROID is mm).  The
URDFs are assets: the app's URDF layer fetches ``package://droid/<robot>.urdf``
(``<robot>``: each arm's robot file, e.g. ``reis_v15``) over the same connection.

Read-only (docs/design.md §10 "Observers never command"): it reads the Brain's databases
like a task; the server advertises no capability (no client publish, services,
parameters or playback control), and whatever a client sends beside subscriptions
and asset requests is dropped and counted (printed at exit).  It binds 127.0.0.1
and refuses a non-loopback ``--host`` without ``--token``; with a token a small
gate (aiohttp) listens on ``--host:--port``, needs ``?token=TOKEN`` or
``Authorization: Bearer TOKEN``, and relays to the SDK server on a private
loopback port.  With ``--file`` it plays the recording at its pace in a loop.

Exit: 0 on SIGINT/SIGTERM; 1 cell not up, port in use (named); 2 bad arguments, bad
file, the SDK not installed (``pip install droid[foxglove]``).
"""
from __future__ import annotations

import asyncio
import bisect
import errno
import hmac
import json
import math
import signal
import socket
import sys
import time
import xml.etree.ElementTree as ET

import numpy as np

from droid.cli import BadInput, DroidError, RuntimeFailure, is_loopback, rate_hz, run, tcp_port
from droid.observe.mcapfile import stamp
from droid.observe.scene import WORKPIECE_BOX_MM, SceneBuilder, is_arm, quat
from droid.observe.view import GUARD, guard_view

PROG = "droid-foxglove"
DEFAULT_PORT = 8765
DEFAULT_RATE_HZ = 30.0
SCENE_PERIOD_S = 0.5  # /scene (workpiece + seam map) at most twice a second
PACKAGE = "package://droid/"  # asset URIs: package://droid/<robot>.urdf
#: the WebSocket subprotocol: the SDK's server speaks ``foxglove.sdk.v1``, which is the Foxglove WebSocket
#: protocol ``foxglove.websocket.v1`` renamed (same messages); the token gate accepts either from a client
SUBPROTOCOL = "foxglove.sdk.v1"
OLD_SUBPROTOCOL = "foxglove.websocket.v1"
M_PER_MM = 1e-3
#: client operations the token gate relays to the SDK server; everything else is dropped
GATE_OPS = frozenset({"subscribe", "unsubscribe", "fetchAsset"})
GATE_MAX_MSG_BYTES = 65536
#: the guard's closest-pair line by state (droid-web's colours)
GUARD_COLORS = {"clear": {"r": 0.25, "g": 0.88, "b": 0.44, "a": 1.0}, "slowing": {"r": 1.0, "g": 0.69, "b": 0.13, "a": 1.0},
                "stopped": {"r": 1.0, "g": 0.19, "b": 0.19, "a": 1.0}}

# ------------------------------------------------------------------ URDF forward kinematics


def _rpy_matrix(r: float, p: float, y: float) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw [rad]: R = Rz(y) Ry(p) Rx(r)."""
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _axis_angle(axis: np.ndarray, a: float) -> np.ndarray:
    """4x4 rotation by ``a`` [rad] about the unit ``axis`` (Rodrigues)."""
    x, y, z = axis
    c, s, C = math.cos(a), math.sin(a), 1.0 - math.cos(a)
    T = np.eye(4)
    T[:3, :3] = [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                 [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                 [z * x * C - y * s, z * y * C + x * s, c + z * z * C]]
    return T


class UrdfChain:
    """The joints of a URDF text, for its links' transforms at joint angles [rad] (lengths in m)."""

    def __init__(self, text: str) -> None:
        root = ET.fromstring(text)
        self.root_link = None
        self.joints: list[tuple[str, str, str, str, np.ndarray, np.ndarray]] = []  # name, type, parent, child, T, axis
        children = set()
        for j in root.findall("joint"):
            o = j.find("origin")
            T = np.eye(4)
            if o is not None:
                T[:3, 3] = [float(v) for v in o.get("xyz", "0 0 0").split()]
                T[:3, :3] = _rpy_matrix(*[float(v) for v in o.get("rpy", "0 0 0").split()])
            ax = j.find("axis")
            axis = np.array([float(v) for v in (ax.get("xyz") if ax is not None else "1 0 0").split()])
            child = j.find("child").get("link")
            children.add(child)
            self.joints.append((j.get("name"), j.get("type"), j.find("parent").get("link"), child, T,
                                axis / (np.linalg.norm(axis) or 1.0)))
        links = [ln.get("name") for ln in root.findall("link")]
        roots = [ln for ln in links if ln not in children]
        self.root_link = roots[0] if roots else links[0]
        self.movable = [j[0] for j in self.joints if j[1] in ("revolute", "continuous")]

    def transforms(self, q_rad: dict[str, float]) -> list[tuple[str, str, np.ndarray]]:
        """``[(parent link, child link, 4x4 of child in parent [m])]`` for every joint (a joint not in
        ``q_rad`` at 0)."""
        out = []
        for name, typ, parent, child, T, axis in self.joints:
            if typ in ("revolute", "continuous"):
                T = T @ _axis_angle(axis, float(q_rad.get(name, 0.0)))
            elif typ == "prismatic":
                T = T.copy()
                T[:3, 3] += axis * float(q_rad.get(name, 0.0))
            out.append((parent, child, T))
        return out

    def link_pose(self, link: str, q_rad: dict[str, float]) -> np.ndarray:
        """4x4 of ``link`` in the root link [m]."""
        by_child = {c: (p, T) for p, c, T in self.transforms(q_rad)}
        T = np.eye(4)
        while link in by_child:
            parent, Tj = by_child[link]
            T = Tj @ T
            link = parent
        return T


# ------------------------------------------------------------------ the core: snapshots -> messages


def _vec(p, scale: float = M_PER_MM) -> dict:
    return {"x": float(p[0]) * scale, "y": float(p[1]) * scale, "z": float(p[2]) * scale}


def _pose(T: np.ndarray, scale: float = M_PER_MM) -> dict:
    return {"position": _vec(T[:3, 3], scale), "orientation": quat(T[:3, :3])}


def _tf(ts: dict, parent: str, child: str, T: np.ndarray, scale: float = M_PER_MM) -> dict:
    return {"timestamp": ts, "parent_frame_id": parent, "child_frame_id": child,
            "translation": _vec(T[:3, 3], scale), "rotation": quat(T[:3, :3])}


_IDENT = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}


def _line(points_mm, color: dict) -> dict:
    return {"type": 0, "pose": _IDENT, "thickness": 2.0, "scale_invariant": True,
            "points": [_vec(p) for p in points_mm], "color": color, "colors": [], "indices": []}


class FoxgloveFeed:
    """Status snapshots of a cell -> Foxglove messages, as plain dicts in the well-known schemas' JSON form.

    ``meta``: a recording's ``droid`` metadata (or the same built from a live cell,
    :func:`droid.observe.mcapfile.cell_meta`).  Pure: no SDK, no I/O; the shell turns the
    dicts into the SDK's messages (:func:`sdk_message`).
    """

    def __init__(self, meta: dict) -> None:
        from droid.brain.db.layouts import LAYOUTS
        from droid.kinematics import load_robot

        self.meta = meta
        subs = meta.get("subunits", [])
        self.scene = SceneBuilder(subs, meta.get("scene", {}))
        by_name = {lay.name: lay for lay in LAYOUTS.values()}
        self.status_layouts = {}  # subunit -> Layout of its Status
        for s in subs:
            area = (s.get("areas") or {}).get("status")
            if area and area.get("layout") in by_name:
                self.status_layouts[s["name"]] = by_name[area["layout"]]
        self.arms: dict[str, tuple] = {}  # arm -> (robot name | None, model | None, UrdfChain | None)
        self.assets: dict[str, bytes] = {}
        for s in subs:
            if not is_arm(s):
                continue
            robot, model, chain = s.get("robot"), None, None
            if robot:
                try:
                    model = load_robot(robot)
                except Exception:  # noqa: BLE001 -- an unknown robot file: its Status pose only
                    model = None
            if model is not None:
                text = self._urdf(model)
                if text is not None:
                    chain = UrdfChain(text)
                    self.assets[f"{PACKAGE}{robot}.urdf"] = text.encode()
            self.arms[s["name"]] = (robot, model, chain)
        self._scene_t = -math.inf
        self._topics = self.topics()

    @staticmethod
    def _urdf(model) -> str | None:
        try:
            from droid.kinematics.urdf import robot_urdf
        except ImportError:  # a droid without URDF export: no assets, no link frames
            return None
        try:
            return robot_urdf(model)
        except (ValueError, KeyError):  # a robot file that makes no valid URDF (RobotFileError is a ValueError)
            return None

    # the channels: topic -> schema ("foxglove.X" for a well-known schema, else a JSON Schema dict)
    def topics(self) -> dict[str, object]:
        from droid.observe.schemas import record_schema

        t: dict[str, object] = {"/tf": "foxglove.FrameTransforms", "/scene": "foxglove.SceneUpdate",
                                "/laser": "foxglove.SceneUpdate", "/tool_pose": "foxglove.PoseInFrame"}
        for arm, (_, model, _) in self.arms.items():
            if model is not None:
                t[f"/{arm}/joint_states"] = "foxglove.JointStates"
        for sub, lay in self.status_layouts.items():
            t[f"/{sub}/status"] = record_schema(lay)
        if GUARD not in self.status_layouts:  # the collision guard (no subunit of that name)
            from droid.brain.db.layouts import GUARD_STATUS_LAYOUT
            from droid.observe.schemas import GUARD_VIEW

            t["/guard"], t["/guard/closest"] = GUARD_VIEW, "foxglove.SceneUpdate"
            g = self.meta.get("guard")
            if g is not None and g.get("run"):  # a record droid-guard writes
                t["/guard/status"] = record_schema(GUARD_STATUS_LAYOUT)
        return t

    def asset(self, uri: str) -> bytes | None:
        """The bytes of an asset (``package://droid/<robot>.urdf`` of one of the cell's arms), else None."""
        return self.assets.get(uri)

    def reset(self) -> None:
        """Start over (a recording played again from its start): the seam map is cleared."""
        self.scene.reset_seam()
        self._scene_t = -math.inf

    def joints_deg(self, arm: str, d: dict) -> np.ndarray | None:
        model = self.arms[arm][1]
        if model is None or "encoder_pos" not in d:
            return None
        return model.gearing.counts_to_joints(np.asarray(d["encoder_pos"], float))

    def step(self, tick: int, t_ns: int, statuses: dict[str, dict], now_s: float | None = None) -> dict[str, dict]:
        """The messages of one snapshot: ``{topic: message dict}`` (``/scene`` only every
        :data:`SCENE_PERIOD_S` of ``now_s`` [s]; ``t_ns`` [ns] stamps every message)."""
        ts = stamp(t_ns)
        guard = None
        if GUARD not in self.status_layouts:
            statuses = dict(statuses)
            guard = statuses.pop(GUARD, None)
        geo = self.scene.step(statuses)
        out: dict[str, dict] = {}
        tfs = [_tf(ts, "world", name, T) for name, T in geo["frames"].items()]
        for arm, (_, model, chain) in self.arms.items():
            d = statuses.get(arm)
            q = None if d is None else self.joints_deg(arm, d)
            if q is None:
                continue
            out[f"/{arm}/joint_states"] = {"timestamp": ts, "joints": [
                {"name": f"joint_{i + 1}", "position": math.radians(float(q[i]))} for i in range(6)]}
            if chain is not None:
                q_rad = {f"joint_{i + 1}": math.radians(float(q[i])) for i in range(6)}
                tfs.append(_tf(ts, f"{arm}/base", f"{arm}/{chain.root_link}", np.eye(4)))
                tfs += [_tf(ts, f"{arm}/{p}", f"{arm}/{c}", T, 1.0) for p, c, T in chain.transforms(q_rad)]
        out["/tf"] = {"transforms": tfs}
        tool = geo["frames"].get("tool")
        if tool is not None:
            out["/tool_pose"] = {"timestamp": ts, "frame_id": "world", "pose": _pose(tool)}
        if geo["laser"]:
            out["/laser"] = {"deletions": [], "entities": [
                {"timestamp": ts, "frame_id": "world", "id": "laser", "lifetime": stamp(0), "frame_locked": False,
                 "cubes": [], "lines": [_line(geo["laser"], {"r": 1.0, "g": 0.0, "b": 0.0, "a": 1.0})]}]}
        now = time.monotonic() if now_s is None else now_s
        if now - self._scene_t >= SCENE_PERIOD_S:
            self._scene_t = now
            ents = []
            if "workpiece" in geo["frames"]:
                lx, wy, tz = WORKPIECE_BOX_MM
                ents.append({"timestamp": ts, "frame_id": "workpiece", "id": "workpiece", "lifetime": stamp(0),
                             "frame_locked": True, "lines": [],
                             "cubes": [{"pose": {"position": _vec((lx / 2, 0, -tz / 2)),
                                                 "orientation": _IDENT["orientation"]},
                                        "size": _vec((lx, wy, tz)), "color": {"r": 0.6, "g": 0.6, "b": 0.65, "a": 0.8}}]})
            ents.append({"timestamp": ts, "frame_id": "world", "id": "seam", "lifetime": stamp(0),
                         "frame_locked": False, "cubes": [],
                         "lines": [_line(geo["seam"], {"r": 1.0, "g": 0.8, "b": 0.0, "a": 1.0})] if geo["seam"] else []})
            out["/scene"] = {"deletions": [], "entities": ents}
        for sub, d in statuses.items():
            if sub in self.status_layouts:
                out[f"/{sub}/status"] = dict(d, _tick=int(tick), _subunit=sub)
        if GUARD not in self.status_layouts:
            newest = max((int(d.get("tick", 0)) for d in statuses.values()), default=0)
            g = out["/guard"] = guard_view(self.meta.get("guard"), guard, newest)
            if guard is not None and "/guard/status" in self._topics:
                out["/guard/status"] = dict(guard, _tick=int(tick), _subunit=GUARD)
            lines = ([_line(g["points"], GUARD_COLORS.get(g["state"], GUARD_COLORS["clear"]))]
                     if g["points"] and g["state"] != "off" else [])
            out["/guard/closest"] = {"deletions": [], "entities": [
                {"timestamp": ts, "frame_id": "world", "id": "guard_closest", "lifetime": stamp(0),
                 "frame_locked": False, "cubes": [], "lines": lines}]}
        return out


# ------------------------------------------------------------------ the shell: the SDK


def import_sdk():
    """The ``foxglove`` SDK module, or BadInput (exit 2) naming the extra that installs it."""
    try:
        import foxglove  # noqa: F401
        import foxglove.channels  # noqa: F401
        import foxglove.messages  # noqa: F401
        from foxglove.websocket import Capability  # noqa: F401
    except ImportError:
        raise BadInput("the Foxglove SDK is not installed: pip install 'droid[foxglove]' (PyPI foxglove-sdk)") from None
    return sys.modules["foxglove"]


#: dict key -> SDK message class name of the nested value (lists: of each item)
_NESTED = {"timestamp": "Timestamp", "lifetime": "Duration", "translation": "Vector3", "rotation": "Quaternion",
           "position": "Vector3", "orientation": "Quaternion", "size": "Vector3", "color": "Color", "pose": "Pose",
           "transforms": "FrameTransform", "entities": "SceneEntity", "cubes": "CubePrimitive",
           "lines": "LinePrimitive", "points": "Point3", "colors": "Color", "joints": "JointState", "poses": "Pose",
           "deletions": "SceneEntityDeletion"}


def sdk_message(schema: str, d: dict):
    """A well-known message dict (the JSON form, ``schema`` e.g. ``foxglove.SceneUpdate``) as the SDK's object."""
    from foxglove import messages as M

    def build(cls_name: str, v):
        cls = getattr(M, cls_name)
        if cls_name in ("Timestamp", "Duration"):
            return cls(sec=int(v["sec"]), nsec=int(v["nsec"]))
        kw = {}
        for k, x in v.items():
            if k in _NESTED and isinstance(x, (dict, list)):  # JointState.position is a number
                sub = _NESTED[k]
                kw[k] = [build(sub, i) for i in x] if isinstance(x, list) else build(sub, x)
            elif k == "type" and cls_name == "LinePrimitive":
                T = M.LinePrimitiveLineType
                kw[k] = (T.LineStrip, T.LineLoop, T.LineList)[int(x)]
            else:
                kw[k] = x
        return cls(**kw)

    return build(schema.removeprefix("foxglove."), d)


class ReadOnlyListener:
    """The server's listener: counts what clients try beside subscribing, acts on none of it."""

    def __init__(self) -> None:
        self.refused = 0
        self.subscriptions = 0

    def on_subscribe(self, client, channel) -> None:
        self.subscriptions += 1

    def on_unsubscribe(self, client, channel) -> None:
        pass

    def on_client_advertise(self, client, channel) -> None:
        self.refused += 1  # read-only: a client channel is never listened to

    def on_client_unadvertise(self, client, client_channel_id) -> None:
        self.refused += 1

    def on_message_data(self, client, client_channel_id, data) -> None:
        self.refused += 1  # and what it publishes is dropped

    def on_get_parameters(self, client, param_names, request_id=None):
        self.refused += 1
        return []

    def on_set_parameters(self, client, parameters, request_id=None):
        self.refused += 1
        return []


class FoxgloveServer:
    """The SDK's WebSocket server with one channel per topic of a :class:`FoxgloveFeed` (own SDK context)."""

    def __init__(self, feed: FoxgloveFeed, host: str, port: int, name: str) -> None:
        fg = import_sdk()
        from foxglove import channels as C
        from foxglove.websocket import Capability  # noqa: F401 -- none is advertised

        self.feed = feed
        self.listener = ReadOnlyListener()
        self.ctx = fg.Context()
        typed = {"foxglove.FrameTransforms": C.FrameTransformsChannel, "foxglove.SceneUpdate": C.SceneUpdateChannel,
                 "foxglove.PoseInFrame": C.PoseInFrameChannel, "foxglove.JointStates": C.JointStatesChannel}
        self.channels: dict[str, tuple[object, object]] = {}  # topic -> (schema, channel)
        for topic, schema in feed.topics().items():
            if isinstance(schema, str):
                ch = typed[schema](topic, context=self.ctx)
            else:
                ch = fg.Channel(topic, schema=schema, context=self.ctx)
            self.channels[topic] = (schema, ch)
        self.asset_requests = 0
        try:
            self.server = fg.start_server(name=name, host=host, port=port, capabilities=[],
                                          server_listener=self.listener, supported_encodings=[],
                                          services=None, asset_handler=self._asset, context=self.ctx)
        except Exception as exc:  # noqa: BLE001 -- the SDK raises RuntimeError with the OS error's text
            raise _bind_error(exc, host, port) from None
        self.port = self.server.port

    def _asset(self, uri: str) -> bytes | None:
        self.asset_requests += 1
        return self.feed.asset(uri)

    def listened(self) -> bool:
        """Whether any client subscribes to any channel."""
        return any(ch.has_sinks() for _, ch in self.channels.values())

    def publish(self, msgs: dict[str, dict], log_time_ns: int) -> int:
        """Log every message; returns how many went to a channel someone listens to."""
        n = 0
        for topic, d in msgs.items():
            schema, ch = self.channels.get(topic, (None, None))
            if ch is None or not ch.has_sinks():
                continue
            ch.log(sdk_message(schema, d) if isinstance(schema, str) else d, log_time=log_time_ns)
            n += 1
        return n

    def stop(self) -> None:
        self.server.stop()


def _bind_error(exc: Exception, host: str, port: int) -> DroidError:
    text = str(exc)
    low = text.lower()
    if "in use" in low or f"os error {errno.EADDRINUSE}" in low:
        return RuntimeFailure(f"port {port} on {host} is in use")
    if "assign requested address" in low or f"os error {errno.EADDRNOTAVAIL}" in low or "invalid" in low:
        return BadInput(f"--host {host}: not an address of this host")
    return RuntimeFailure(f"cannot listen on {host}:{port}: {text.splitlines()[0] if text else type(exc).__name__}")


# ------------------------------------------------------------------ where the snapshots come from


class LiveFeedSource:
    """The Brain's databases of a running cell, read-only (like a task)."""

    mode = "live"

    def __init__(self, cell) -> None:
        from droid.observe.mcapfile import cell_meta
        from droid.observe.sampler import CellSampler
        from droid.observe.scene import scene_meta

        self.meta = cell_meta(cell, "live", scene_meta(cell))
        self.sampler = CellSampler(cell).connect()  # RuntimeFailure (exit 1) when the cell is not up

    def next(self) -> tuple[int, dict[str, dict], bool]:
        """``(tick, statuses, restarted)`` now."""
        from droid.observe import schemas

        st = {s: schemas.record_to_dict(r) for s, a, _, r in self.sampler.read() if a == "status"}
        return max((int(d.get("tick", 0)) for d in st.values()), default=0), st, False

    def close(self) -> None:
        self.sampler.close()


class FileFeedSource:
    """A recording played at its pace (its heartbeat rate), from its start again after its end."""

    mode = "file"

    def __init__(self, path: str, clock=time.monotonic) -> None:
        from droid.observe.mcapfile import read_recording

        self.rec = read_recording(path)  # BadRecording (exit 2)
        if not self.rec.ticks:
            raise BadInput(f"{path}: the recording holds no tick")
        self.meta = self.rec.meta
        self.hz = float(self.meta.get("heartbeat_hz", 60.0)) or 60.0
        self.clock = clock
        self.t0 = clock()
        self.i = -1
        self.passed: list[dict[str, dict]] = []  # statuses of ticks skipped since the last call (for the seam map)

    def statuses(self, i: int) -> dict[str, dict]:
        fr = self.rec.frames[i]
        return {t.split("/")[1]: m[-1] for t, m in fr.items() if t.endswith("/status") and t.count("/") == 2}

    def next(self) -> tuple[int, dict[str, dict], bool]:
        ticks = self.rec.ticks
        span = ticks[-1] - ticks[0] + 1
        elapsed = int((self.clock() - self.t0) * self.hz)
        restarted = elapsed >= span or (self.i >= 0 and elapsed < 0)
        if restarted:
            self.t0 = self.clock()
            elapsed, self.i = 0, -1
        j = max(0, bisect.bisect_right(ticks, ticks[0] + elapsed) - 1)
        self.passed = [self.statuses(k) for k in range(self.i + 1, j)] if j > self.i + 1 else []
        self.i = j
        return ticks[j], self.statuses(j), restarted

    def close(self) -> None:
        pass


class Pump:
    """Each ``rate`` period: one snapshot from ``source`` through ``feed`` to ``server``."""

    def __init__(self, source, feed: FoxgloveFeed, server: FoxgloveServer, rate: float) -> None:
        self.src, self.feed, self.server = source, feed, server
        self.period_s = 1.0 / rate
        self.read_errors = 0
        self.published = 0

    def once(self) -> None:
        try:
            tick, st, restarted = self.src.next()
        except DroidError as exc:  # a database held too long: skip this period, say so now and then
            self.read_errors += 1
            if self.read_errors == 1 or self.read_errors % 30 == 0:
                print(f"{PROG}: {exc}", file=sys.stderr, flush=True)
            return
        if restarted:
            self.feed.reset()
        for passed in getattr(self.src, "passed", []):
            self.feed.scene.step(passed)  # ticks between two periods still extend the seam map
        if not self.server.listened():
            self.feed.scene.step(st)  # nobody listens: keep the seam map only
            return
        now = time.time_ns()
        self.published += self.server.publish(self.feed.step(tick, now, st), now)

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        nxt = loop.time()
        while True:
            nxt += self.period_s
            self.once()
            delay = nxt - loop.time()
            if delay < -1.0:
                nxt = loop.time()
            await asyncio.sleep(max(0.0, delay))


# ------------------------------------------------------------------ the token gate


class TokenGate:
    """An aiohttp WebSocket front on ``host:port`` that needs the token and relays to the SDK server
    (on a private loopback port): subscriptions and asset requests go on, everything else is dropped."""

    def __init__(self, token: str, upstream_port: int) -> None:
        from aiohttp import web

        self.token = token
        self.upstream = f"ws://127.0.0.1:{upstream_port}/"
        self.dropped = 0
        self.app = web.Application()
        self.app.add_routes([web.get("/{tail:.*}", self.ws)])
        self.runner = None

    def _authorized(self, request) -> bool:
        got = request.query.get("token") or request.headers.get("Authorization", "").removeprefix("Bearer ")
        return hmac.compare_digest(got.encode(), self.token.encode())

    async def ws(self, request):
        import aiohttp
        from aiohttp import WSMsgType, web

        if not self._authorized(request):
            return web.json_response({"error": "token required"}, status=401)
        down = web.WebSocketResponse(protocols=(SUBPROTOCOL, OLD_SUBPROTOCOL), max_msg_size=GATE_MAX_MSG_BYTES, heartbeat=10.0)
        await down.prepare(request)
        async with aiohttp.ClientSession() as s:
            try:
                up = await s.ws_connect(self.upstream, protocols=(SUBPROTOCOL,), max_msg_size=0)
            except aiohttp.ClientError:
                await down.close()
                return down

            async def upward():
                async for msg in down:
                    if msg.type == WSMsgType.TEXT and self._allowed(msg.data):
                        await up.send_str(msg.data)
                    elif msg.type in (WSMsgType.TEXT, WSMsgType.BINARY):
                        self.dropped += 1  # binary = client message data or service calls: never relayed
                await up.close()

            async def downward():
                async for msg in up:
                    if msg.type == WSMsgType.TEXT:
                        await down.send_str(msg.data)
                    elif msg.type == WSMsgType.BINARY:
                        await down.send_bytes(msg.data)
                await down.close()

            tasks = [asyncio.ensure_future(upward()), asyncio.ensure_future(downward())]
            try:
                await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            finally:
                for t in tasks:
                    t.cancel()
                await up.close()
        return down

    def _allowed(self, text: str) -> bool:
        try:
            op = json.loads(text).get("op")
        except (ValueError, AttributeError):
            return False
        return op in GATE_OPS

    async def start(self, host: str, port: int) -> None:
        from aiohttp import web

        self.runner = web.AppRunner(self.app, access_log=None, handle_signals=False)
        await self.runner.setup()
        site = web.TCPSite(self.runner, host, port, reuse_address=False)
        try:
            await site.start()
        except OSError as exc:
            await self.runner.cleanup()
            if isinstance(exc, socket.gaierror):
                raise BadInput(f"--host {host}: not an address of this host") from None
            if exc.errno == errno.EADDRINUSE:
                raise RuntimeFailure(f"port {port} on {host} is in use") from None
            if exc.errno in (errno.EADDRNOTAVAIL, errno.EINVAL):
                raise BadInput(f"--host {host}: not an address of this host") from None
            raise RuntimeFailure(f"cannot listen on {host}:{port}: {exc.strerror}") from None

    async def stop(self) -> None:
        if self.runner is not None:
            await self.runner.cleanup()


# ------------------------------------------------------------------ the program


def check_host(host: str, token: str | None) -> None:
    """droid-web's rule: loopback only unless a token is given (checked before anything binds)."""
    if token is not None and (len(token) < 8 or not token.isprintable()):
        raise BadInput("--token must be at least 8 printable characters")
    if not is_loopback(host) and token is None:
        raise BadInput(f"--host {host} is not loopback: refused without --token TOKEN")


def open_source(file: str | None, args):
    if file:
        return FileFeedSource(file)
    from droid.brain.runtime.program import open_cell

    return LiveFeedSource(open_cell(args))


class Service:
    """Source + feed + SDK server (+ the token gate): what droid-foxglove runs, and droid-web --foxglove."""

    def __init__(self, source, host: str, port: int, token: str | None, rate: float) -> None:
        self.src = source
        self.host, self.port, self.token = host, port, token
        name = f"DROID {source.meta.get('cell')} ({source.mode})"
        try:
            self.feed = FoxgloveFeed(source.meta)
            # with a token the SDK server listens on a private loopback port behind the gate
            self.server = FoxgloveServer(self.feed, "127.0.0.1" if token else host, 0 if token else port, name)
        except BaseException:
            source.close()  # the source is the service's from here on
            raise
        self.gate = TokenGate(token, self.server.port) if token else None
        self.pump = Pump(source, self.feed, self.server, rate)

    async def run(self, stop: asyncio.Event) -> None:
        if self.gate is not None:
            await self.gate.start(self.host, self.port)
        print(f"{PROG}: serving {self.src.mode} view of {self.src.meta.get('cell')} on ws://{self.host}:{self.port}"
              f"{'/?token=...' if self.token else ''} ({SUBPROTOCOL})", file=sys.stderr, flush=True)
        task = asyncio.create_task(self.pump.run())
        try:
            await stop.wait()
        finally:
            task.cancel()
            if self.gate is not None:
                await self.gate.stop()

    def close(self) -> None:
        self.server.stop()
        self.src.close()
        # without client capabilities the SDK drops client channels and their data itself (it logs them);
        # the listener counts whatever reaches it anyway, the gate what it did not relay
        refused = self.server.listener.refused + (self.gate.dropped if self.gate else 0)
        tail = f", {refused} client messages refused (read-only)" if self.gate is not None or refused else ""
        print(f"{PROG}: stopped; {self.pump.published} messages published{tail}", file=sys.stderr, flush=True)


async def _serve(svc: Service) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    await svc.run(stop)


def add_arguments(ap) -> None:
    ap.add_argument("--port", type=tcp_port, default=DEFAULT_PORT, metavar="PORT",
                    help=f"TCP port (default {DEFAULT_PORT})")
    ap.add_argument("--host", default="127.0.0.1", metavar="ADDR",
                    help="address to listen on (default 127.0.0.1; any other needs --token)")
    ap.add_argument("--token", default=None, metavar="TOKEN",
                    help="require ?token=TOKEN (or Authorization: Bearer TOKEN) to connect")
    ap.add_argument("--file", default=None, metavar="F.mcap", help="play a recording (in a loop) instead of the live cell")
    ap.add_argument("--rate", type=rate_hz(0.1, 120.0), default=DEFAULT_RATE_HZ, metavar="HZ",
                    help=f"snapshots published per second (default {DEFAULT_RATE_HZ:g})")


@run
def main(argv=None) -> int:
    from droid.brain.runtime.program import parser

    ap = parser(PROG, "Serve the cell (or a recording) read-only to the Foxglove app / Lichtblick over "
                      "the Foxglove WebSocket protocol.")
    add_arguments(ap)
    args = ap.parse_args(argv)
    check_host(args.host, args.token)
    import_sdk()
    svc = Service(open_source(args.file, args), args.host, args.port, args.token, args.rate)
    try:
        asyncio.run(_serve(svc))
    finally:
        svc.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
