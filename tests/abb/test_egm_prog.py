"""droid-egm's shell (issue 26): --help, bad input (exit 2), a port in use (exit 1), and one run
on loopback UDP against the cell's databases (no cell brought up: the databases are created by
the test, datagrams come from a socket of the test, the program stops on SIGTERM)."""
from __future__ import annotations

import os
import select
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from abb_robot_client._egm_protobuf import egm_pb2
from droid.brain.cell.cellfile import load_cell
from droid.brain.db.databases import create_databases, open_local
from droid.brain.db.layouts import HOMED
from droid.brain.db.shmdb import Database, db_name, remove_cell_objects
from droid.kinematics import load_robot
from droid.subunits.abb.egm_layout import EGM_STATUS_LAYOUT
from tests.abb.egm_helpers import robot_bytes

PROG = [sys.executable, "-m", "droid.subunits.abb.egm_prog"]


def cell_text(name: str, run: str, egm: str) -> str:
    return f"""
[cell]
name = "{name}"
heartbeat_hz = 60.0
stale_ticks = 12
sched_fifo = false
run_dir = "{run}"

[brain]
host = "brain"
heartbeat = "ipc://{{run}}/heartbeat"
names = "ipc://{{run}}/names"

[subunits.abb]
class = "arm6r"
robot = "abb_irb2400"
host = "abb"
agent = "ipc://{{run}}/abb.agent"
relay = "ipc://{{run}}/abb.relay"
base = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
programs = ["droid-reis-agent", "droid-planner", "droid-egm"]
egm = "{egm}"
"""


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def run_prog(*args, timeout=60):
    return subprocess.run(PROG + list(args), capture_output=True, text=True, timeout=timeout)


def test_help():
    r = run_prog("--help")
    assert r.returncode == 0 and "--cell" in r.stdout and "subunit" in r.stdout


@pytest.mark.parametrize("egm", ["tcp://127.0.0.1:6510", "udp://127.0.0.1:0", "udp://127.0.0.1:70000",
                                 "udp://127.0.0.1", "6510"])
def test_bad_egm_url_is_one_line_exit_2(tmp_path, cell_name, egm):
    path = tmp_path / "c.toml"
    path.write_text(cell_text(cell_name, str(tmp_path / "run"), egm))
    r = run_prog("--cell", str(path), "abb")
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "egm" in r.stderr and "Traceback" not in r.stderr


def test_not_an_arm_or_unknown_subunit_exit_2(tmp_path, cell_name):
    path = tmp_path / "c.toml"
    path.write_text(cell_text(cell_name, str(tmp_path / "run"), "udp://127.0.0.1:6510"))
    r = run_prog("--cell", str(path), "nosuch")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


def test_port_in_use_is_one_line_exit_1(tmp_path, cell_name):
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    try:
        port = holder.getsockname()[1]
        path = tmp_path / "c.toml"
        path.write_text(cell_text(cell_name, str(tmp_path / "run"), f"udp://127.0.0.1:{port}"))
        r = run_prog("--cell", str(path), "abb")
        assert r.returncode == 1, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "in use" in lines[0] and str(port) in lines[0]
    finally:
        holder.close()


def test_runs_on_loopback_homes_and_answers(tmp_path, cell_name):
    """Feedback datagrams in -> homed, encoder_pos and the EGM record; every one answered with an
    EgmSensor to its source port; garbage counted in the presence record; SIGTERM -> exit 0."""
    port = free_udp_port()
    path = tmp_path / "c.toml"
    path.write_text(cell_text(cell_name, str(tmp_path / "run"), f"udp://127.0.0.1:{port}"))
    cell = load_cell(path)
    sub = cell.subunit("abb")
    for db in create_databases(cell):
        db.close()
    ctrl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ctrl.bind(("127.0.0.1", 0))
    p = subprocess.Popen(PROG + ["--cell", str(path), "abb"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    status = open_local(cell, sub, "ctrl_status")
    q = [5.0, 10.0, 15.0, 20.0, 25.0, 30.0]
    try:
        replies = []
        seq = 0
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and (len(replies) < 20 or int(status.read()["homed"]) != HOMED):
            assert p.poll() is None, p.stderr.read()
            seq += 1
            ctrl.sendto(robot_bytes(seq, joints=q), ("127.0.0.1", port))
            if seq % 10 == 0:
                ctrl.sendto(b"\xff\xfe garbage", ("127.0.0.1", port))
            if select.select([ctrl], [], [], 0.004)[0]:
                replies.append(ctrl.recvfrom(65536))
        assert len(replies) >= 20
        m = egm_pb2.EgmSensor()
        m.ParseFromString(replies[-1][0])
        assert replies[-1][1] == ("127.0.0.1", port)
        assert m.header.mtype == egm_pb2.EgmHeader.MSGTYPE_CORRECTION
        assert np.allclose(list(m.planned.joints.joints), q)  # holds where the arm is
        st = status.read()
        assert int(st["homed"]) == HOMED and int(st["fault"]) == 0
        model = load_robot("abb_irb2400")
        assert np.allclose(model.gearing.counts_to_joints(st["encoder_pos"].astype(float)), q, atol=0.002)
        egm = Database(db_name(cell.name, "abb", "egm"), EGM_STATUS_LAYOUT)
        try:
            rec = egm.read()
            end = time.monotonic() + 10.0  # written each heartbeat period (own clock: no ticks here)
            while int(rec["accepted"]) < 20 and time.monotonic() < end:
                time.sleep(0.02)
                rec = egm.read()
            assert int(rec["malformed"]) >= 1 and int(rec["accepted"]) >= 20
            assert np.allclose(rec["feedback_deg"], q)
        finally:
            egm.close()
    finally:
        status.close()
        ctrl.close()
        p.send_signal(signal.SIGTERM)
        try:
            out, err = p.communicate(timeout=20)
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()
        left = set(os.listdir("/dev/shm"))
        remove_cell_objects(cell.name)
    assert p.returncode == 0, err
    assert f"droid.{cell.name}.abb.egm" not in left  # droid-egm removes its record at exit
    assert f"droid.{cell.name}.abb.ctrl_status" in left  # (the cell's databases are not its own)


def interposed_cell(tmp_path, cell_name, public_port: int, inner: str):
    path = tmp_path / "c.toml"
    path.write_text(cell_text(cell_name, str(tmp_path / "run"), f"udp://127.0.0.1:{public_port}")
                    + f'\n[interpose]\n"udp://127.0.0.1:{public_port}" = "{inner}"\n')
    return path


def test_interposed_binds_the_inner_address(tmp_path, cell_name):
    """With an [interpose] entry (droid-fault on the EGM link) droid-egm binds the inner address:
    a port in use there is its exit 1, a malformed one exit 2; the public port may be taken (by
    the fault proxy, here a test socket) and it still answers at the inner address."""
    holder, public = socket.socket(socket.AF_INET, socket.SOCK_DGRAM), socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ctrl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for s in (holder, public, ctrl):
        s.bind(("127.0.0.1", 0))
    p = None
    try:
        pport, hport = public.getsockname()[1], holder.getsockname()[1]
        path = interposed_cell(tmp_path, cell_name, pport, f"udp://127.0.0.1:{hport}")
        r = run_prog("--cell", str(path), "abb")
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 1 and len(lines) == 1 and "in use" in lines[0] and str(hport) in lines[0], r.stderr
        path = interposed_cell(tmp_path, cell_name, pport, "udp://127.0.0.1:0")
        r = run_prog("--cell", str(path), "abb")
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "interpose" in r.stderr, r.stderr

        inner = free_udp_port()
        path = interposed_cell(tmp_path, cell_name, pport, f"udp://127.0.0.1:{inner}")
        for db in create_databases(load_cell(path)):
            db.close()
        p = subprocess.Popen(PROG + ["--cell", str(path), "abb"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
        reply, seq = None, 0
        deadline = time.monotonic() + 30.0
        while reply is None and time.monotonic() < deadline:
            assert p.poll() is None, p.stderr.read()
            seq += 1
            ctrl.sendto(robot_bytes(seq), ("127.0.0.1", inner))
            if select.select([ctrl], [], [], 0.01)[0]:
                reply = ctrl.recvfrom(65536)
        assert reply is not None and reply[1] == ("127.0.0.1", inner)
        m = egm_pb2.EgmSensor()
        m.ParseFromString(reply[0])
        assert m.header.mtype == egm_pb2.EgmHeader.MSGTYPE_CORRECTION
    finally:
        for s in (holder, public, ctrl):
            s.close()
        if p is not None:
            p.send_signal(signal.SIGTERM)
            try:
                p.communicate(timeout=20)
            finally:
                if p.poll() is None:
                    p.kill()
                    p.wait()
        remove_cell_objects(cell_name)
    assert p.returncode == 0


def stream(port: int, joints, stop) -> None:
    """A controller streaming EgmRobot with ``joints`` to 127.0.0.1:``port`` every 4 ms until ``stop``."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        seq = 0
        while not stop.is_set():
            seq += 1
            try:
                s.sendto(robot_bytes(seq, joints=joints), ("127.0.0.1", port))
            except OSError:
                pass  # nobody bound yet
            time.sleep(0.004)


@pytest.mark.parametrize("how", ["program", pytest.param("cell up", marks=pytest.mark.integration)])
def test_a_controller_with_another_joint_count_is_refused_at_start(tmp_path, cell_name, how):
    """Issue 26: the robot file has 6 joints; a controller streaming 7 (an arm on a track, say) is
    refused at start with one line and exit 2 -- by droid-egm itself, and so by `droid-cell up`,
    which brings nothing up."""
    import threading

    from droid.brain.db.shmdb import cell_objects
    from tests.brain.cellutil import droid

    port = free_udp_port()
    path = tmp_path / "c.toml"
    path.write_text(cell_text(cell_name, str(tmp_path / "run"), f"udp://127.0.0.1:{port}"))
    cell = load_cell(path)
    stop = threading.Event()
    th = threading.Thread(target=stream, args=(port, [0.0, 10.0, 10.0, 0.0, 60.0, 0.0, 250.0], stop), daemon=True)
    th.start()
    try:
        if how == "program":
            for db in create_databases(cell):
                db.close()
            r = run_prog("--cell", str(path), "abb")
        else:
            r = droid("droid.brain.runtime.launcher", "up", "--cell", str(path), timeout=120)
    finally:
        stop.set()
        th.join(5)
        if how == "cell up":
            droid("droid.brain.runtime.launcher", "down", "--cell", str(path), timeout=60)
        remove_cell_objects(cell.name)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "reports 7 joints" in lines[0] and "abb_irb2400 has 6" in lines[0], r.stderr
    assert cell_objects(cell.name) == []
