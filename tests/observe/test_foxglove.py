"""droid-foxglove: the Foxglove WebSocket server (docs/observe.md, "Foxglove").

Served from a recording made in lockstep (``--file``) or from a cell's databases without
any program (``db_cell``) -- never a live cell.  The client (tests/observe/foxglove_client.py)
speaks the Foxglove WebSocket protocol on aiohttp and decodes the binary frames, protobuf
payloads from the descriptors the server advertises.
"""
from __future__ import annotations

import asyncio
import math
import socket
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

import aiohttp
import numpy as np
import pytest

from tests.brain.cellutil import ROOT, free_port, in_process, make_cell_file
from tests.observe.foxglove_client import OLD_SUBPROTOCOL, SUBPROTOCOL, FoxgloveClient
from tests.observe.webutil import lockstep_recording, stop_process, taken_port

WELL_KNOWN = {"/tf": "foxglove.FrameTransforms", "/scene": "foxglove.SceneUpdate", "/laser": "foxglove.SceneUpdate",
              "/tool_pose": "foxglove.PoseInFrame", "/arm1/joint_states": "foxglove.JointStates",
              "/gmf1/joint_states": "foxglove.JointStates",
              "/guard/closest": "foxglove.SceneUpdate"}  # the collision guard's closest pair (off here: empty)
STATUS = {"/arm1/status": "droid.arm_status", "/gmf1/status": "droid.arm_status",
          "/mvs/status": "droid.sensor_status", "/tool/status": "droid.sensor_status",
          "/guard": "droid.guard_view"}  # the guard as the viewers show it: "off" in a lockstep seam trial


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    return lockstep_recording(tmp_path_factory.mktemp("fox") / "trial.mcap")


class FoxServer:
    """droid-foxglove (or droid-web --foxglove) as a process, until it accepts TCP connections on ``port``."""

    def __init__(self, *args: str, module: str = "droid.observe.foxglove", port: int | None = None,
                 wait_port: int | None = None) -> None:
        self.port = port or free_port()
        argv = [sys.executable, "-m", module, *args]
        if "--port" not in args:
            argv += ["--port", str(self.port)]
        self.proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60
        while True:
            if self.proc.poll() is not None:
                raise AssertionError(f"{module} exited {self.proc.returncode}: {self.proc.stderr.read()}")
            try:
                with socket.create_connection(("127.0.0.1", wait_port or self.port), timeout=1):
                    return
            except OSError:
                if time.monotonic() > deadline:
                    self.stop()
                    raise AssertionError(f"{module} did not start listening")
                time.sleep(0.1)

    def stop(self) -> tuple[int, str]:
        stop_process(self.proc, 15)
        err = self.proc.stderr.read()
        self.proc.stdout.close()
        self.proc.stderr.close()
        return self.proc.returncode, err

    def __enter__(self) -> "FoxServer":
        return self

    def __exit__(self, *exc) -> None:
        if not self.proc.stderr.closed:
            self.stop()


def talk(url: str, body, protocol: str = SUBPROTOCOL):
    """Run ``body(client)`` on one connection; returns what it returns."""

    async def go():
        async with aiohttp.ClientSession() as s:
            async with s.ws_connect(url, protocols=(protocol,), max_msg_size=0) as ws:
                c = FoxgloveClient(ws)
                c.protocol = ws.protocol
                return await body(c)

    return asyncio.run(asyncio.wait_for(go(), 60))


# ------------------------------------------------------------------ the core (no server)


def test_feed_urdf_links_follow_the_joints(recording):
    """The URDF links published on /tf end where the D-H forward kinematics of the same Status
    counts ends (eq. 4.1): the URDF asset and the joint states describe the recorded arm."""
    from droid.kinematics import load_robot
    from droid.kinematics.urdf import robot_urdf
    from droid.observe.foxglove import FileFeedSource, FoxgloveFeed, UrdfChain

    src = FileFeedSource(recording)
    feed = FoxgloveFeed(src.meta)
    assert set(feed.topics()) == set(WELL_KNOWN) | set(STATUS)
    assert feed.asset("package://droid/reis_v15.urdf") == robot_urdf(load_robot("reis_v15")).encode()
    assert feed.asset("package://droid/fanuc_s400.urdf") is not None
    for bad in ("package://droid/../cells/sim.toml", "package://droid/nosuch.urdf", "file:///etc/passwd", ""):
        assert feed.asset(bad) is None
    for i in (0, len(src.rec.ticks) // 2, len(src.rec.ticks) - 1):
        st = src.statuses(i)
        msgs = feed.step(src.rec.ticks[i], 10**18, st, now_s=float(i))
        assert set(msgs) <= set(feed.topics())
        tf = {(t["parent_frame_id"], t["child_frame_id"]): t for t in msgs["/tf"]["transforms"]}
        for arm in ("arm1", "gmf1"):
            q_deg = feed.joints_deg(arm, st[arm])
            js = msgs[f"/{arm}/joint_states"]["joints"]
            assert [j["name"] for j in js] == [f"joint_{k}" for k in range(1, 7)]
            assert np.allclose([j["position"] for j in js], np.radians(q_deg), atol=1e-12)
            chain = UrdfChain(robot_urdf(feed.arms[arm][1]))
            T = chain.link_pose("tool0", {j["name"]: j["position"] for j in js})
            T[:3, 3] *= 1000.0  # m -> mm
            base = feed.scene.arms[arm][1]
            dh6 = feed.scene.link_frames(arm, st[arm])[-1]
            assert np.abs(base @ T - dh6).max() < 1e-6
            assert (f"{arm}/link_5", f"{arm}/link_6") in tf and (f"{arm}/base", f"{arm}/base_link") in tf
        assert ("world", "tool") in tf and ("world", "workpiece") in tf
        assert msgs["/arm1/status"]["_subunit"] == "arm1"


def test_urdf_chain_reads_origins_and_axes():
    from droid.observe.foxglove import UrdfChain

    text = """<robot name="r"><link name="a"/><link name="b"/><link name="c"/>
      <joint name="j1" type="revolute"><parent link="a"/><child link="b"/>
        <origin xyz="1 0 0" rpy="0 0 1.5707963267948966"/><axis xyz="0 0 1"/></joint>
      <joint name="j2" type="fixed"><parent link="b"/><child link="c"/><origin xyz="0 2 0"/></joint></robot>"""
    ch = UrdfChain(text)
    assert ch.root_link == "a" and ch.movable == ["j1"]
    # c at j1 = 0: yaw 90 deg then (0, 2, 0) -> (-2, 0, 0) from b at (1, 0, 0)
    assert np.allclose(ch.link_pose("c", {})[:3, 3], [-1.0, 0.0, 0.0])
    # j1 = -90 deg undoes the yaw
    assert np.allclose(ch.link_pose("c", {"j1": -math.pi / 2})[:3, 3], [1.0, 2.0, 0.0])


# ------------------------------------------------------------------ the server, over its WebSocket


def test_one_message_of_each_schema(recording):
    from droid.kinematics import load_robot
    from droid.kinematics.urdf import robot_urdf

    async def body(c: FoxgloveClient):
        await c.read_handshake(want_channels=len(WELL_KNOWN) + len(STATUS))
        got = await c.one_of_each(list(c.channels))
        ok = await c.fetch_asset("package://droid/reis_v15.urdf", 7)
        missing = await c.fetch_asset("package://droid/../../etc/passwd", 8)
        return c, got, ok, missing

    with FoxServer("--file", recording, "--rate", "30") as srv:
        c, got, ok, missing = talk(f"ws://127.0.0.1:{srv.port}/", body)
        code, err = srv.stop()
    assert code == 0, err
    info = c.server_info
    assert info["name"].startswith("DROID lockstep-1.3")
    # read-only: the only capability is serving assets (no clientPublish, services, parameters, playback)
    assert info["capabilities"] == ["assets"], info
    topics = {ch["topic"]: ch for ch in c.channels.values()}
    assert {t: ch["schemaName"] for t, ch in topics.items()} == {**WELL_KNOWN, **STATUS}
    for t in WELL_KNOWN:
        assert topics[t]["encoding"] == "protobuf" and topics[t]["schemaEncoding"] == "protobuf"
    for t in STATUS:
        assert topics[t]["encoding"] == "json" and topics[t]["schemaEncoding"] == "jsonschema"
    msg = {c.channels[cid]["topic"]: m for cid, (_, m) in got.items()}
    assert set(msg) == set(topics)
    assert all(t > 1_600_000_000 * 10**9 for t, _ in got.values())  # wall-clock log times [ns]
    # foxglove.JointStates: six joints in rad
    for arm in ("arm1", "gmf1"):
        js = msg[f"/{arm}/joint_states"]
        assert [j.name for j in js.joints] == [f"joint_{k}" for k in range(1, 7)]
        assert all(math.isfinite(j.position) and abs(j.position) < 2 * math.pi for j in js.joints)
        assert js.timestamp.seconds > 0
    # foxglove.FrameTransforms: the scene frames and the URDF links, metres
    tf = {(t.parent_frame_id, t.child_frame_id): t for t in msg["/tf"].transforms}
    for pair in [("world", "arm1/base"), ("world", "arm1/wcp"), ("world", "tool"), ("world", "sensor"),
                 ("world", "workpiece"), ("world", "gmf1/base"), ("arm1/base", "arm1/base_link"),
                 ("arm1/base_link", "arm1/link_1"), ("arm1/link_5", "arm1/link_6"), ("gmf1/flange", "gmf1/tool0")]:
        assert pair in tf, pair
    assert tf[("world", "gmf1/base")].translation.x == pytest.approx(2.0)  # the holder's base at 2000 mm
    q = tf[("world", "tool")].rotation
    assert math.isclose(q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2, 1.0, rel_tol=1e-9)
    # foxglove.SceneUpdate: the workpiece plate and the seam map; the laser line
    ents = {e.id: e for e in msg["/scene"].entities}
    assert ents["workpiece"].frame_id == "workpiece" and len(ents["workpiece"].cubes) == 1
    assert ents["workpiece"].cubes[0].size.x == pytest.approx(0.4)
    assert "seam" in ents
    laser = msg["/laser"].entities[0]
    assert laser.id == "laser" and len(laser.lines[0].points) == 2
    p0, p1 = laser.lines[0].points
    assert math.dist((p0.x, p0.y, p0.z), (p1.x, p1.y, p1.z)) == pytest.approx(0.06)  # 2 x 30 mm
    # foxglove.PoseInFrame: the tool point
    assert msg["/tool_pose"].frame_id == "world"
    assert msg["/tool_pose"].pose.position.x == pytest.approx(tf[("world", "tool")].translation.x, abs=0.05)
    # the Status records: JSON of their JSON Schema
    import json

    for t in STATUS:
        schema = json.loads(topics[t]["schema"])
        assert schema["title"] == STATUS[t]
        if t == "/guard":  # no record: what the viewers say of a cell without a guard
            assert msg[t]["state"] == "off" and msg[t]["distance_mm"] is None and msg[t]["why"]
            continue
        assert set(schema["required"]) <= set(msg[t]) and msg[t]["_subunit"] == t.split("/")[1]
    # the URDF asset is robot_urdf of the robot file; anything else is not found
    status, data, _ = ok
    assert status == 0 and data == robot_urdf(load_robot("reis_v15")).encode()
    assert ET.fromstring(data).get("name") == "reis_v15"
    assert missing[0] == 1 and missing[1] == b""


def test_client_publish_never_reaches_a_database(db_cell):
    """Advertising a client channel, publishing on it, calling a service and setting parameters:
    the server offers none of these, stays up, and not one byte of any database changes."""
    import struct

    from droid.observe import schemas
    from droid.observe.sampler import CellSampler

    cell, path = db_cell

    def snapshot():
        with CellSampler(cell) as s:
            return {(sub, area): schemas.record_to_dict(r) for sub, area, _, r in s.read()}

    before = snapshot()
    assert ("arm1", "command") in before

    async def body(c: FoxgloveClient):
        await c.read_handshake(want_channels=4)
        ws = c.ws
        await ws.send_str('{"op": "advertise", "channels": [{"id": 1, "topic": "/arm1/command", '
                          '"encoding": "json", "schemaName": "droid.arm_command"}]}')
        payload = b'{"cmd_mode": 3, "x": 1000.0, "cmd_id": 99}'
        await ws.send_bytes(b"\x01" + struct.pack("<I", 1) + payload)  # client message data
        await ws.send_bytes(b"\x02" + struct.pack("<III", 1, 1, 4) + b"json" + payload)  # service call
        await ws.send_str('{"op": "setParameters", "parameters": [{"name": "cmd_mode", "value": 3}], "id": "x"}')
        await ws.send_str('{"op": "unadvertise", "channelIds": [1]}')
        await ws.send_str("not json")
        # the server still serves: one Status of arm1 after all that
        arm = next(cid for cid, ch in c.channels.items() if ch["topic"] == "/arm1/status")
        got = await c.one_of_each([arm])
        return c, got[arm][1]

    with FoxServer("--cell", str(path)) as srv:
        c, status = talk(f"ws://127.0.0.1:{srv.port}/", body)
        time.sleep(0.3)
        assert srv.proc.poll() is None
        code, err = srv.stop()
    assert code == 0, err
    assert "clientPublish" not in c.server_info["capabilities"] and "services" not in c.server_info["capabilities"]
    assert status["_subunit"] == "arm1"
    assert snapshot() == before  # every record, header (seq, writer pid) included
    assert "stopped;" in err


def test_token_gate(recording):
    """--token: no connection without it; with it (either protocol name) subscriptions work and
    anything else a client sends is dropped."""
    token = "s3cret-token"

    async def body(c: FoxgloveClient):
        await c.read_handshake(want_channels=len(WELL_KNOWN) + len(STATUS))
        await c.ws.send_bytes(b"\x01\x01\x00\x00\x00{}")
        await c.ws.send_str('{"op": "advertise", "channels": []}')
        tf = next(cid for cid, ch in c.channels.items() if ch["topic"] == "/tf")
        got = await c.one_of_each([tf])
        return c, got[tf][1]

    with FoxServer("--file", recording, "--token", token) as srv:
        url = f"ws://127.0.0.1:{srv.port}/"

        async def refused():
            async with aiohttp.ClientSession() as s:
                with pytest.raises(aiohttp.WSServerHandshakeError) as e:
                    await s.ws_connect(url + "?token=wrong-token", protocols=(SUBPROTOCOL,))
                assert e.value.status == 401
                with pytest.raises(aiohttp.WSServerHandshakeError):
                    await s.ws_connect(url, protocols=(SUBPROTOCOL,))

        asyncio.run(refused())
        for proto in (SUBPROTOCOL, OLD_SUBPROTOCOL):
            c, tf = talk(f"{url}?token={token}", body, protocol=proto)
            assert c.protocol == proto
            assert c.server_info["capabilities"] == ["assets"]
            assert any(t.child_frame_id == "tool" for t in tf.transforms)
        code, err = srv.stop()
    assert code == 0, err
    refused_n = int(err.split(" client messages refused")[0].rsplit(" ", 1)[1])
    assert refused_n >= 4  # two dropped by the gate per connection


# ------------------------------------------------------------------ refusals


def run_fox(*args, module="droid.observe.foxglove"):
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, cwd=ROOT, timeout=60)


def test_non_loopback_refused_before_binding(recording, monkeypatch, capsys):
    """A non-loopback --host without --token is refused before any socket or server is made."""
    import droid.observe.foxglove as fox

    made = []
    monkeypatch.setattr(fox, "Service", lambda *a, **k: made.append(a))
    monkeypatch.setattr(fox, "open_source", lambda *a, **k: made.append(a))
    for host in ("0.0.0.0", "10.1.2.3", "::", "example.org"):
        assert fox.main(["--host", host, "--file", recording]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "not loopback" in err[0] and "--token" in err[0]
    assert made == []
    for host in ("127.0.0.1", "::1", "localhost", "127.0.0.2"):
        fox.check_host(host, None)
    fox.check_host("0.0.0.0", "long-enough-token")


def test_refusals(recording, tmp_path, cell_name, capsys):
    import droid.observe.foxglove as fox

    # refused before anything is started: main() in-process (the rest run the program)
    out = in_process(fox.main, capsys, "--file", str(tmp_path / "none.mcap"))
    assert out.returncode == 2 and "no such file" in out.stderr and len(out.stderr.strip().splitlines()) == 1
    (tmp_path / "bad.mcap").write_bytes(b"not mcap at all")
    out = in_process(fox.main, capsys, "--file", str(tmp_path / "bad.mcap"))
    assert out.returncode == 2 and "not an MCAP file" in out.stderr
    out = in_process(fox.main, capsys, "--port", "70000")
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1
    with taken_port() as port:
        out = run_fox("--port", str(port), "--file", recording)
        assert out.returncode == 1 and f"port {port}" in out.stderr and len(out.stderr.strip().splitlines()) == 1
        out = run_fox("--port", str(port), "--file", recording, "--token", "s3cret-token")
        assert out.returncode == 1 and f"port {port}" in out.stderr
    # a cell that is not up
    out = run_fox("--cell", str(make_cell_file(tmp_path, cell_name)), "--port", str(free_port()))
    assert out.returncode == 1 and "does not exist" in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_droid_web_serves_foxglove_beside_the_page(recording):
    import json
    import urllib.request

    fport = free_port()

    async def body(c: FoxgloveClient):
        await c.read_handshake(want_channels=len(WELL_KNOWN) + len(STATUS))
        js = next(cid for cid, ch in c.channels.items() if ch["topic"] == "/arm1/joint_states")
        return (await c.one_of_each([js]))[js][1]

    with FoxServer("--file", recording, "--foxglove", str(fport), module="droid.observe.web", wait_port=fport) as srv:
        with urllib.request.urlopen(f"http://127.0.0.1:{srv.port}/api/cell", timeout=10) as r:
            assert json.loads(r.read())["source"] == "file"
        js = talk(f"ws://127.0.0.1:{fport}/", body)
        assert len(js.joints) == 6
        code, err = srv.stop()
    assert code == 0, err
    # the same port twice, and the Foxglove side's port in use: one line each
    out = run_fox("--file", recording, "--port", "8111", "--foxglove", "8111", module="droid.observe.web")
    assert out.returncode == 2 and "--foxglove 8111" in out.stderr and len(out.stderr.strip().splitlines()) == 1
    with taken_port() as port:
        out = run_fox("--file", recording, "--port", str(free_port()), "--foxglove", str(port), module="droid.observe.web")
    assert out.returncode == 1 and f"port {port}" in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_without_the_sdk_one_line_naming_the_extra(recording, monkeypatch, capsys):
    import droid.observe.foxglove as fox
    import droid.observe.web as web

    for mod in ("foxglove", "foxglove.channels", "foxglove.messages", "foxglove.websocket"):
        monkeypatch.setitem(sys.modules, mod, None)  # import fails as if not installed
    assert fox.main(["--file", recording]) == 2
    assert web.main(["--file", recording, "--foxglove", "8765"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all("droid[foxglove]" in line for line in err), err
