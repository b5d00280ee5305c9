"""The karel_s400 world device behind real transports: a pty link, socket://, and its cards in shm."""
import os
import socket
import time

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.cli import BadInput
from droid.sim.world import build_world
from droid.subunits.gmf1 import karel_wire as kw
from droid.subunits.gmf1.port import PortLink, serial_opener
from droid.subunits.gmf1.quad04 import open_bank
from tests.brain.cellutil import make_cell_file

GMF1_ONLY = """
[cell]
name = "{name}"
run_dir = "{run}"

[world]
rate_hz = 1000.0
seed = 4

[world.devices.gmf1]
type = "karel_s400"
{device}

[subunits.gmf1]
class = "arm6r"
robot = "fanuc_s400"
base = [2000.0, 0.0, 0.0, 180.0, 0.0, 0.0]
{sub}
"""


def cell_file(tmp_path, name, device="", sub=""):
    p = tmp_path / f"{name}.toml"
    p.write_text(GMF1_ONLY.format(name=name, run=tmp_path / "run", device=device, sub=sub))
    return load_cell(p)


def advance(world, seconds, dt=0.001):
    for _ in range(int(round(seconds / dt))):
        world.advance(dt)


def exchange(world, link, request: bytes, n_replies: int, virtual_s: float = 10.0):
    """Write a request and step the world until ``n_replies`` reply lines came back.

    A pty hands bytes over through the kernel's flip buffers (asynchronously): step the
    world in 10 ms slices with a short real pause so they get through even on a loaded host."""
    link.write(request)
    splitter = kw.LineSplitter()
    lines = []
    for _ in range(int(virtual_s / 0.01)):
        advance(world, 0.01)
        lines += splitter.feed(link.read())
        if len(lines) >= n_replies:
            break
        time.sleep(0.0005)
    return [kw.parse_reply(ln) for ln in lines]


def test_pty_round_trip_and_cards_in_shm(tmp_path, cell_name):
    cell = cell_file(tmp_path, cell_name)
    world = build_world(cell)
    try:
        link_path = tmp_path / "run" / "gmf1.tty"
        assert os.path.islink(link_path) and os.readlink(link_path).startswith("/dev/pts/")
        link = PortLink(serial_opener(str(link_path), 9600))
        assert link.open()
        assert exchange(world, link, kw.format_stat(5), 1) == [kw.Reply(kw.STAT, 5, state=kw.IDLE)]
        bank = open_bank([f"shm://droid.{cell_name}.gmf1.quad0", f"shm://droid.{cell_name}.gmf1.quad1"])
        raw0, _ = bank.read_joints()
        advance(world, 0.5)  # past the interpreter's cycle of the STAT line
        lines = exchange(world, link, kw.format_home(6), 2)
        assert [r.kind for r in lines] == [kw.ACK, kw.DONE]
        raw1, _ = bank.read_joints()
        assert np.any(raw1 != raw0)  # the joints moved: the counters counted
        bank.close()
        link.close()
    finally:
        world.close()
    assert not os.path.exists(tmp_path / "run" / "gmf1.tty")
    assert not any(n.startswith(f"droid.{cell_name}.") for n in os.listdir("/dev/shm"))


def test_port_vanishes_when_the_world_goes(tmp_path, cell_name):
    cell = cell_file(tmp_path, cell_name)
    world = build_world(cell)
    link = PortLink(serial_opener(str(tmp_path / "run" / "gmf1.tty"), 9600))
    try:
        assert link.open()
    finally:
        world.close()
    assert link.read() == b"" and not link.is_open
    assert link.last_error
    assert not link.open()  # the link path is gone: reopening fails quietly


def test_socket_url(tmp_path, cell_name):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"socket://127.0.0.1:{port}"
    cell = cell_file(tmp_path, cell_name, sub=f'serial = "{url}"')
    world = build_world(cell)
    try:
        link = PortLink(serial_opener(url, 9600))
        assert link.open()
        assert [r.cmd_id for r in exchange(world, link, kw.format_stat(9), 1)] == [9]
        link.close()
    finally:
        world.close()


# Rows alike in shape only to other tables of bad input: each spoils its own key.
@pytest.mark.parametrize("device, sub, msg", [
    ('colour = "red"', "", "unknown option"),
    ("start_deg = [0, 0, 0, 0, 170, 0]", "", "joint limits"),
    ("start_deg = [1, 2]", "", "start_deg"),
    ("wcp = [800, 0, 1000, 0, 0, 0]", "", "out of reach"),
    ("wcp = [800, 0, 1200, 0, 0, 0]\nstart_deg = [0, 0, 0, 0, 0, 0]", "", "not both"),
    ("cycle_hz = -1", "", "cycle_hz"),
    ('dynamics = "yes"', "", "dynamics must be true or false"),
    ("inpos_deg = 0", "", "inpos_deg"),
    ("", 'encoders = ["mem:///tmp/x", "shm://a"]', "shm://"),
    ("", 'encoders = ["shm://a"]', "encoders"),
    ("", 'serial = "loop://"', "pty path or socket"),
    ("", "baud = 0", "baud"),
    ("", 'wheels = 4', "unknown key"),
])
def test_bad_device_options_are_refused(tmp_path, cell_name, device, sub, msg):
    with pytest.raises(BadInput, match=msg):  # by the cell file's numbers (droid.numbers) or the device
        build_world(cell_file(tmp_path, cell_name, device=device, sub=sub))
    assert not any(n.startswith(f"droid.{cell_name}.") for n in os.listdir("/dev/shm"))


def test_the_shipped_cell_declares_the_device_and_programs(tmp_path, cell_name):
    cell = load_cell(make_cell_file(tmp_path, cell_name))
    devices = cell.world["devices"]
    assert [d["subunit"] for d in devices.values() if d["type"] == "karel_s400"] == ["gmf1"]
    progs = cell.subunit("gmf1").programs
    assert {"droid-gmf1-agent", "droid-gmf1-serial", "droid-gmf1-encoder"} <= set(progs)


def test_bad_serial_url_is_bad_input():
    with pytest.raises(BadInput):
        serial_opener("nosuch://x", 9600)


def test_missing_pty_is_not_fatal(tmp_path):
    link = PortLink(serial_opener(str(tmp_path / "none.tty"), 9600))
    assert not link.open() and "No such file" in link.last_error
    assert link.read() == b"" and link.write(b"x") is False


def test_power_up_wrist_centre_pose(tmp_path, cell_name):
    """``wcp`` puts the arm at a global wrist-centre pose at power-up (as the fixed stand-in does)."""
    from droid.kinematics.transforms import pose_to_T

    cell = cell_file(tmp_path, cell_name, device="wcp = [800.0, 0.0, 1200.0, 0.0, 0.0, 0.0]")
    world = build_world(cell)
    try:
        np.testing.assert_allclose(world.devices["gmf1"].wcp_global(), pose_to_T(800, 0, 1200, 0, 0, 0),
                                   atol=1e-9)
    finally:
        world.close()


def test_the_twin_runs_the_robot_files_dynamics_unless_told_not_to(tmp_path, cell_name):
    """fanuc_s400.toml has [dynamics] and [axis_servo]: the device's arm follows KAREL's path
    through them by default; ``dynamics = false`` is the ideal arm on the path."""
    for device, on in (("", True), ("dynamics = false", False)):
        world = build_world(cell_file(tmp_path, cell_name, device=device))
        try:
            c = world.devices["gmf1"].controller
            assert c.p.dynamics is on and (c.arm is not None) is on
        finally:
            world.close()
