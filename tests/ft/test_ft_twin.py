"""The Net F/T twin (droid/sim/ft/netft.py), read by the independent client pyNetFT and by droid-ft's
driver; its place in cells/sim.toml (docs/ft.md).

World time is the twin's own: the tests step it (in lockstep, or from a small background thread
at 1 ms of world time a step) and count records and samples in world time, never on the wall
clock.  Everything listens on 127.0.0.1 at ports the kernel picks, and is closed by the test.
"""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.kinematics.transforms import pose_to_T
from droid.sim.ft.netft import (GRAVITY_MPS2, SENSOR_MODELS, NetFtTwin, NetFtTwinDevice, make_netft,
                                wrench_on_sensor)
from droid.sim.world import build_world
from droid.subunits.ft import rdt
from droid.subunits.ft.prog import FtCore, FtStation, wrench_in_tool

GAMMA = SENSOR_MODELS["gamma"]
SIGMA = np.array(GAMMA.noise)
TOOL = pose_to_T(0.0, 0.0, 150.0, -90.0, 90.0, 180.0)


class Arm:
    """A stand-in arm twin: a fixed wrist pose, and optionally a contact wrench (the hook)."""

    def __init__(self, T=None, contact=None):
        self.T = pose_to_T(800.0, 0.0, 900.0, 0.0, 90.0, 0.0) if T is None else T
        if contact is not None:
            self.contact_wrench_N_Nm = lambda: contact

    def wcp_global(self):
        return self.T.copy()


def twin_device(arm=None, mass=1.5, com=(0.0, 0.0, 60.0), rate=500.0, seed=3) -> NetFtTwinDevice:
    dev = NetFtTwinDevice("ft", NetFtTwin(GAMMA, seed, rate), arm or Arm(), np.eye(4), TOOL, mass, com)
    dev.serve()
    return dev


class Stepper:
    """Steps the twin's world time (1 ms a step) from a thread until stopped; a step waits a
    little wall time so the client's socket reads keep up (the verdicts count world time)."""

    def __init__(self, dev):
        self.dev = dev
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self):
        while not self.stop.is_set():
            with self.lock:
                self.dev.advance(0.001)
            time.sleep(0.0005)

    def close(self):
        self.stop.set()
        self.thread.join(timeout=10)


def within_noise(measured, truth, k=6.0):
    return np.all(np.abs(np.asarray(measured) - np.asarray(truth)) <= k * SIGMA + 1e-6)


# ------------------------------------------------------------------ the independent client


def test_pynetft_streams_the_twin_at_its_rate_biases_and_stops():
    from pynetft import Client, Config, ForceUnit, TorqueUnit

    dev = twin_device()
    stepper = Stepper(dev)
    cfg = Config(sensor_host="127.0.0.1", rdt_port=dev.port, http_port=dev.http_port, receive_timeout=5.0,
                 configuration_timeout=5.0, configuration_connect_timeout=5.0)
    try:
        f_true, m_true = dev.true_wrench()
        truth = np.r_[f_true, m_true]
        with Client(cfg) as client:
            samples = client.samples(timeout=30.0)
            got = [next(samples) for _ in range(40)]
            # units as the page says; torque in N-mm, converted here to compare
            assert got[0].force_unit is ForceUnit.NEWTON and got[0].torque_unit is TorqueUnit.NEWTON_MILLIMETER
            for s in got:
                assert s.status == 0
                assert within_noise([*s.force, *(np.array(s.torque) / 1000.0)], truth), (s, truth)
            # the rate, in world time: 500 records a second of a device sampling at 7000 a second
            seqs = [s.rdt_sequence for s in got]
            fts = [s.ft_sequence for s in got]
            # in order; a record lost on a loaded host (a full socket buffer) shows as a gap the
            # client counts, and the rate holds across it: FT samples per RDT record, exactly
            assert all(b > a for a, b in zip(seqs, seqs[1:]))
            assert set(np.diff(fts) / np.diff(seqs)) == {rdt.FT_SAMPLES_PER_S // 500}
            h = client.health()  # a gap is a record lost on the wire or dropped by the client's own queue
            assert h.lost_count + h.python_queue_dropped_count >= (seqs[-1] - seqs[0] + 1) - len(seqs)
            assert client.health().malformed_count == 0
            client.bias()
            for _ in range(400):  # until the biased records arrive (bounded)
                s = next(samples)
                if within_noise([*s.force, *(np.array(s.torque) / 1000.0)], np.zeros(6), k=9.0):
                    break
            else:
                pytest.fail("no biased record after the bias command")
            assert np.allclose(dev.twin.bias, truth, atol=float(np.max(6 * SIGMA)))
        # leaving the client sent the stop
        for _ in range(2000):
            with stepper.lock:
                if not dev.twin.streaming:
                    break
            time.sleep(0.005)
        assert not dev.twin.streaming
        with stepper.lock:
            sent = dev.twin.sent
            dev.advance(0.1)
            assert dev.twin.sent == sent  # nothing more once stopped
    finally:
        stepper.close()
        dev.close()


# ---------------------------------------------------------------- droid-ft's driver, lockstep


def lockstep(dev, station, t_ns, steps=20):
    """Step the twin 1 ms and droid-ft's station at 10 ms, ``steps`` station cycles; datagrams on
    loopback are delivered before the next cycle's poll (a short sleep; bounded)."""
    f = None
    for _ in range(steps):
        for _ in range(10):
            dev.advance(0.001)
        time.sleep(0.002)
        t_ns += 10_000_000
        f = station.step(t_ns)
    return f, t_ns


def test_droid_ft_reads_the_twin_in_the_sensor_and_tool_frames():
    dev = twin_device()
    drv = rdt.open_ft(dev.url)
    try:
        station = FtStation(drv, FtCore(TOOL, stale_ns=200_000_000), 500_000_000, log=lambda line: None)
        f, t = lockstep(dev, station, 0, steps=30)
        assert f["valid"] == 1 and f["fault"] == 0 and f["records"] > 0
        assert (f["dropped"], f["out_of_order"], f["bad_datagrams"]) == (0, 0, 0)
        f_true, m_true = dev.true_wrench()
        assert within_noise([*f["force_N"], *f["torque_Nm"]], np.r_[f_true, m_true])
        assert np.linalg.norm(f_true) == pytest.approx(1.5 * GRAVITY_MPS2)
        ft, mt = wrench_in_tool(f_true, m_true, TOOL)
        assert np.allclose(f["force_tool_N"], ft, atol=6 * SIGMA.max())
        assert np.allclose(f["torque_tool_Nm"], mt, atol=6 * SIGMA.max() + 0.15 * 6 * SIGMA[:3].max())
        # records stop (the twin is no longer stepped): stale after the rule's span, then asked again
        f = station.step(t + 200_000_000)
        assert f["valid"] == 0 and f["stale"] == 1 and f["fault"] != 0
        f, t = lockstep(dev, station, t + 200_000_000, steps=10)
        assert f["valid"] == 1 and f["out_of_order"] == 0
    finally:
        drv.close()
        dev.close()


def test_bias_and_saturation_through_the_driver():
    heavy = Arm(T=pose_to_T(800.0, 0.0, 900.0, 0.0, 0.0, 0.0))  # sensor z up: the tool hangs along -z
    dev = twin_device(arm=heavy, mass=50.0, com=(0.0, 0.0, 0.0))  # 490 N > the Gamma's 400 N in z
    drv = rdt.open_ft(dev.url + "&bias=1")
    try:
        station = FtStation(drv, FtCore(np.eye(4), 200_000_000), 500_000_000, log=lambda line: None)
        f, _ = lockstep(dev, station, 0, steps=20)
        assert f["saturated"] == 1 and f["status_word"] == rdt.STATUS_ERROR | rdt.STATUS_SATURATION
        assert f["biased"] == 1
        # biased at the clipped reading: what follows reads about zero, still saturated
        assert np.all(np.abs(f["force_N"]) < 6 * SIGMA[:3] + 1e-6)
    finally:
        drv.close()
        dev.close()
    light = twin_device(mass=1.0)
    drv = rdt.open_ft(light.url + "&bias=1")
    try:
        station = FtStation(drv, FtCore(np.eye(4), 200_000_000), 500_000_000, log=lambda line: None)
        f, _ = lockstep(light, station, 0, steps=20)
        assert f["saturated"] == 0 and f["biased"] == 1
        assert within_noise([*f["force_N"], *f["torque_Nm"]], np.zeros(6), k=9.0)
    finally:
        drv.close()
        light.close()


def test_the_twin_refuses_malformed_requests_and_serves_only_its_page():
    import urllib.error
    import urllib.request

    twin = NetFtTwin(GAMMA, 0, 1000.0, noisy=False)
    assert twin.request(b"\x12\x34\x00\x02") is None  # short
    assert twin.request(b"\x43\x21\x00\x02\0\0\0\0") is None  # foreign header
    assert twin.request(rdt.request(0x7777)) is None  # unknown command
    assert twin.bad_requests == 3 and not twin.streaming
    assert twin.request(rdt.request(rdt.CMD_START_REALTIME, 3)) == rdt.CMD_START_REALTIME
    out = twin.step(0.010, ((1.0, 2.0, 3.0), (0.1, 0.2, 0.3)))  # 10 due, 3 asked for
    assert [rdt.RECORD.unpack(r)[0] for r in out] == [1, 2, 3] and not twin.streaming
    assert rdt.RECORD.unpack(out[0])[3:] == (1_000_000, 2_000_000, 3_000_000, 100_000, 200_000, 300_000)
    dev = twin_device()
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{dev.http_port}/netftapi2.xml", timeout=5) as r:
            assert rdt.parse_calibration(r.read()) == GAMMA.calibration
        with pytest.raises(urllib.error.HTTPError):
            urllib.request.urlopen(f"http://127.0.0.1:{dev.http_port}/other.xml", timeout=5)
    finally:
        dev.close()


def test_contact_wrench_hook_adds_to_the_weight():
    T_gs = pose_to_T(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    tool = pose_to_T(0.0, 0.0, 150.0, 0.0, 0.0, 0.0)
    f, m = wrench_on_sensor(T_gs, tool, 0.0, (0, 0, 0), ((10.0, 0.0, 0.0), (0.0, 0.0, 0.5)))
    assert np.allclose(f, [10.0, 0.0, 0.0])
    assert np.allclose(m, [0.0, 1.5, 0.5])  # p x f = (0, 0, 0.15) x (10, 0, 0) = (0, 1.5, 0)
    f, m = wrench_on_sensor(T_gs, tool, 2.0, (0.0, 0.0, 100.0))
    assert np.allclose(f, [0.0, 0.0, -2 * GRAVITY_MPS2]) and np.allclose(m, 0.0)  # CoM on the gravity line
    with_contact = NetFtTwinDevice("ft", NetFtTwin(GAMMA), Arm(contact=((0.0, 0.0, 20.0), (0.0, 0.0, 0.0))),
                                   np.eye(4), TOOL, 1.5, (0.0, 0.0, 60.0))
    without = NetFtTwinDevice("ft", NetFtTwin(GAMMA), Arm(), np.eye(4), TOOL, 1.5, (0.0, 0.0, 60.0))
    R = Arm().T[:3, :3]
    assert np.allclose(with_contact.true_wrench()[0] - without.true_wrench()[0], R.T @ [0.0, 0.0, 20.0])



def test_true_wrench_follows_the_pose_and_the_contact_to_the_bit():
    """true_wrench answers an unchanged pose and contact from its last answer (the arm at rest):
    every answer is wrench_on_sensor's for the pose and contact of that moment."""
    arm = Arm()
    contact = [np.zeros(3), np.zeros(3)]
    arm.contact_wrench_N_Nm = lambda: (contact[0].copy(), contact[1].copy())
    dev = NetFtTwinDevice("ft", NetFtTwin(GAMMA), arm, np.eye(4), TOOL, 1.5, (0.0, 0.0, 60.0))
    poses = [arm.T, arm.T, pose_to_T(800.0, 0.0, 900.0, 0.0, 90.0, 1e-12), arm.T]
    for i, T in enumerate(poses + poses):
        arm.T = T
        if i == 5:
            contact[0] = np.array([0.0, 0.0, 20.0])
        got = dev.true_wrench()
        want = wrench_on_sensor(T @ np.eye(4), TOOL, 1.5, np.array([0.0, 0.0, 60.0]), tuple(contact))
        assert all(g.tobytes() == w.tobytes() for g, w in zip(got, want)), i
        got[0][:] = 0.0  # the caller's copy: the next answer does not change
    dev.tool_mass_kg = 2.0  # another tool at the same pose
    want = wrench_on_sensor(arm.T @ np.eye(4), TOOL, 2.0, np.array([0.0, 0.0, 60.0]), tuple(contact))
    assert all(g.tobytes() == w.tobytes() for g, w in zip(dev.true_wrench(), want))


# ---------------------------------------------------------------------------- the sim cell


def test_the_sim_cell_builds_the_twin_on_the_reis_wrist(tmp_path, cell_name):
    from tests.brain.cellutil import make_cell_file

    cell = load_cell(make_cell_file(tmp_path, cell_name))
    sub = cell.subunit("ft")
    assert sub.cls == "ft6" and sub.host == "arm1"
    opts = cell.world["devices"]["ft_sensor"]
    assert opts["type"] == "netft" and opts["arm"] == "arm1"
    assert rdt.parse_url(opts["device"]).port == rdt.parse_url(sub.options["device"]).port
    assert rdt.parse_url(opts["device"]).http_port == rdt.parse_url(sub.options["device"]).http_port
    # a live cell on this host may hold the shipped ports: serve this one on free ones
    opts["device"] = "netft://127.0.0.1:0?http_port=0"
    world = build_world(cell)
    try:
        dev = world.devices["ft_sensor"]
        assert isinstance(dev, NetFtTwinDevice) and dev.arm is world.devices["arm1"] and dev.sock is None
        world.advance(0.001)  # the first step serves
        assert dev.sock is not None and dev.port != 0
        f, m = dev.true_wrench()
        assert np.linalg.norm(f) == pytest.approx(1.5 * GRAVITY_MPS2)  # the torch's weight, any pose
        assert rdt.fetch_calibration("127.0.0.1", dev.http_port) == GAMMA.calibration
    finally:
        world.close()
    assert dev.sock is None and dev.page is None


def test_a_taken_port_is_one_line_and_the_world_goes_on():
    first = twin_device()
    lines = []
    second = NetFtTwinDevice("ft2", NetFtTwin(GAMMA), Arm(), np.eye(4), TOOL, 1.0, (0, 0, 0),
                             port=first.port, http_port=0, log=lines.append)
    try:
        for _ in range(3000):  # 3 s of world time: three attempts, one line
            second.advance(0.001)
        assert len(lines) == 1 and "cannot serve" in lines[0] and second.sock is None
    finally:
        second.close()
        first.close()


@pytest.mark.parametrize("bad,why", [
    ({"device": "netft://10.0.0.5:49152"}, "loopback address only"),
    ({"arm": "nosuch"}, "no device"),
    ({"model": "nano17"}, "unknown model"),
    ({"rdt_rate_hz": 9000.0}, "rdt_rate_hz"),
    ({"tool_com_mm": [0, 0]}, "tool_com_mm"),
    ({"tool_mass_kg": -1.0}, "tool_mass_kg"),
    ({"colour": "red"}, "unknown key"),
])
def test_bad_twin_options_are_refused_in_one_line(bad, why):
    from droid.cli import BadInput

    class World:
        devices = {"arm1": Arm()}
        seed = 1

    opts = {"device": "netft://127.0.0.1:0?http_port=0", "arm": "arm1"}
    opts.update(bad)
    with pytest.raises(BadInput, match=why) as exc:
        make_netft(World(), "ft_sensor", opts)
    assert "\n" not in str(exc.value)


def test_each_cell_binds_its_twins_on_its_own_loopback_address():
    """{loopback} in a cell file: a 127/8 address from the cell's name, so two cells' Net F/T
    twins (vendor port 49152 each) never contend; never 127.0.0.1; stable for a name."""
    import ipaddress

    from droid.brain.cell.cellfile import builtin_cell_path, load_cell, loopback_address

    names = [f"cell{i}" for i in range(200)]
    addrs = {loopback_address(n) for n in names}
    assert len(addrs) == len(names)  # distinct for distinct names (here)
    for a in addrs:
        ip = ipaddress.ip_address(a)
        assert ip.is_loopback and a != "127.0.0.1"
    assert loopback_address("sim") == loopback_address("sim")
    cell = load_cell(builtin_cell_path())
    assert cell.subunit("ft").options["device"].startswith(f"netft://{loopback_address('sim')}:49152")
    assert cell.world["devices"]["ft_sensor"]["device"].startswith(f"netft://{loopback_address('sim')}:49152")


def test_the_twin_refuses_an_address_that_is_not_loopback():
    from droid.cli import BadInput
    from droid.sim.ft.netft import make_netft

    class W:  # the world a factory sees: no devices needed before the check
        devices = {}
        seed = 0
        cell = type("C", (), {"path": "cell.toml"})()

    with pytest.raises(BadInput, match="loopback"):
        make_netft(W(), "ft_sensor", {"device": "netft://192.0.2.1:49152", "arm": "arm1"})
