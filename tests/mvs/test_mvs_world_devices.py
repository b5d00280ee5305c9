"""World devices: fixed arm twins, the MVS camera/DSP device, the tool-tip sensor; lockstep chain."""
from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest
import serial

from droid.brain.cell.cellfile import load_cell
from droid.brain.plumbing.sensor_line import SensorClientCore, parse_line
from droid.cli import BadInput
from droid.kinematics.transforms import pose_to_T
from droid.sim.lockstep import ORDER_WORLD, Scheduler
from droid.sim.mvs.arm import FixedArm
from droid.sim.mvs.clock import FrameClock
from droid.sim.mvs.lockstep import mvs_lockstep
from droid.sim.mvs.mounts import Mount
from droid.sim.mvs.tool_sensor import pose_for_reading
from droid.sim.workpiece import load_workpiece
from droid.sim.world import build_world
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.dsp import open_dsp
from droid.subunits.mvs.sensor import SensorCore
from tests.brain.cellutil import fixed_seam_cell, make_cell_file

STEP = load_workpiece("step_input")
# The default cell layout (docs/mvs.md): sensor at s = 70 mm, tool tip at s = 20 mm.
ARM1_WCP = [300.0, 100.0, 1340.0, 0.0, 180.0, 0.0]
GMF1_WCP = [800.0, 0.0, 1000.0, 0.0, 0.0, 0.0]
SENSOR_POSE = [-50.0, 0.0, 250.0, 180.0, 90.0, 180.0]
TOOL_POSE = [0.0, 0.0, 250.0, 180.0, 90.0, 180.0]
MOUNT = [-520.0, 100.0, 90.0, 0.0, 0.0, 0.0]
DT = 0.005


def holder_shifted(lateral_mm=0.0, depth_mm=0.0):
    """The holder's WCP moved so both sensors see the seam at +lateral (left) and +depth (farther)."""
    x, y, z, *abc = GMF1_WCP
    return [x, y + lateral_mm, z - depth_mm, *abc]


def rig(holder_wcp=GMF1_WCP, frame=SENSOR_POSE):
    arm = FixedArm("arm1", pose_to_T(*ARM1_WCP))
    holder = FixedArm("gmf1", pose_to_T(*holder_wcp))
    return arm, holder, Mount(arm, holder, pose_to_T(*frame), pose_to_T(*MOUNT))


def test_default_layout_puts_the_sensor_and_the_tool_on_the_seam():
    _, _, sensor = rig()
    assert np.allclose(sensor.T_W(), pose_for_reading(STEP, 70.0), atol=1e-9)
    _, _, tool = rig(frame=TOOL_POSE)
    assert np.allclose(tool.T_W(), pose_for_reading(STEP, 20.0), atol=1e-9)
    # the sensor looks straight down from 50 mm ahead of the tool tip, travel along +x
    assert np.allclose(sensor.T_global()[:3, 3], [350.0, 100.0, 1090.0])
    assert np.allclose(sensor.T_global()[:3, 0], [0, 0, -1]) and np.allclose(sensor.T_global()[:3, 2], [1, 0, 0])


def test_moving_the_holder_is_what_the_sensor_reads():
    _, _, sensor = rig(holder_shifted(3.0, 1.0))
    assert np.allclose(sensor.T_W(), pose_for_reading(STEP, 70.0, 1.0, 3.0), atol=1e-9)


def test_frame_clock_fires_at_its_rate_from_world_steps():
    clock = FrameClock(60.0)
    fired = sum(clock.advance(DT) for _ in range(2000))  # 10 s of a 200 Hz world
    assert fired == 601 and clock.skipped == 0  # t = 0 .. 10 s inclusive
    slow = FrameClock(60.0)
    assert sum(slow.advance(0.05) for _ in range(20)) == 20 and slow.skipped == 41  # 1 s at 20 Hz


@pytest.fixture
def world_cell(tmp_path, cell_name):
    """The default cell (renamed, run dir in tmp), both arms fixed, the seam 3 mm left and 1 mm deeper."""
    path = make_cell_file(tmp_path, cell_name)
    path.write_text(fixed_seam_cell(path.read_text(), lateral_mm=3.0, deeper_mm=1.0))
    return load_cell(path)


def test_camera_device_with_fixed_arms_reports_the_seam_offset(world_cell):
    world = build_world(world_cell)
    board = None
    try:
        for _ in range(4):
            world.advance(DT)
        url = world_cell.world["devices"]["mvs_camera"]["dsp"]
        assert url == f"shm://droid.{world_cell.name}.mvs.dsp"
        board = open_dsp(url)
        core = SensorCore(MvsCalibration())
        readings = []
        for _ in range(10):
            for _ in range(4):  # 20 ms of world: at least one video frame
                world.advance(DT)
            frame = board.wait_frame(1.0)
            assert frame is not None
            readings.append(parse_line(core.step(frame.rows)))
        assert all(r.valid for r in readings)
        ys = [r.y_mm for r in readings]
        xs = [r.x_mm for r in readings]
        # tolerance: the row quantisation (0.2 mm rows) and 0.5 px jitter, 2 % spurious rows
        assert np.median(ys) == pytest.approx(3.0, abs=0.25) and max(abs(y - 3.0) for y in ys) < 0.6
        assert np.median(xs) == pytest.approx(1.0, abs=0.1)
        assert world.devices["mvs_camera"].frames == world.devices["mvs_camera"].clock.fired >= 12
    finally:
        if board is not None:
            board.close()
        world.close()


def test_tool_sensor_device_writes_height_lateral_roll_lines(world_cell):
    world = build_world(world_cell)
    port = None
    try:
        path = world_cell.world["devices"]["tool_sensor"]["serial"]
        port = serial.serial_for_url(path, baudrate=19200, timeout=0)
        for _ in range(200):  # one second of world time
            world.advance(DT)
        client = SensorClientCore()
        data = b""
        deadline = time.monotonic() + 5
        while data.count(b"\n") < 60 and time.monotonic() < deadline:
            data += port.read(port.in_waiting or 1)
        newest = client.feed(data)
        assert client.lines >= 59 and client.valid == client.lines and client.garbled == 0
        # x = height deviation (tip above the seam), y = lateral deviation, roll -- through the lead
        # sensor's noise model (the default cell's: 0.5 px; sigmas 0.012 mm, 0.056 mm, 0.0005 rad)
        assert newest.x_mm == pytest.approx(1.0, abs=0.06) and newest.y_mm == pytest.approx(3.0, abs=0.3)
        assert newest.roll_rad == pytest.approx(0.0, abs=0.003)
        ys = [float(v.split(b",")[1]) for v in data.split(b"\n") if v.count(b",") >= 2]
        assert np.std(ys) > 0.01 and abs(np.mean(ys) - 3.0) < 0.05  # scattered, about the truth
        tool = world.devices["tool_sensor"]
        assert tool.output.dropped_writes == 0 and tool.output.lost_bytes == 0
        assert tool.core.last.s_mm == pytest.approx(-5.0, abs=1e-6)  # 100 mm behind the sensor's 95 mm
    finally:
        if port is not None:
            port.close()
        world.close()
    assert not any(p.endswith(".tty") for p in os.listdir(world_cell.run_dir))


def test_tool_sensor_is_invalid_off_the_workpiece(world_cell):
    from droid.sim.mvs.devices import ToolSensorCore

    core = ToolSensorCore(STEP)
    assert core.step(pose_for_reading(STEP, 20.0, 0.5, -1.0)) == b"0.500,-1.000,0.00000\n"
    assert core.step(pose_for_reading(STEP, -30.0)) == b"invalid\n"  # before the lead-in
    # the sheet turned parallel to the seam, 5 mm off it: it never crosses the seam
    assert core.step(pose_for_reading(STEP, 20.0) @ pose_to_T(0, 0, 0, 0, 90, 0) @ pose_to_T(0, 0, 5, 0, 0, 0)) \
        == b"invalid\n"
    assert (core.lines, core.valid) == (3, 1)


@pytest.mark.parametrize("device,change,message", [
    ("mvs_camera", {"tool_robot": "arm9"}, "tool_robot: no device 'arm9' declared before it"),
    ("mvs_camera", {"holder_robot": "mvs_cable"}, "no device 'mvs_cable' declared before it"),
    ("tool_sensor", {"holder_robot": "mvs_camera"}, "is not an arm twin: it has no wcp_global()"),
    ("mvs_camera", {"sensor_pose": [1, 2, 3]}, "sensor_pose must be 6 finite numbers"),
    ("mvs_camera", {"noise": {"jitter": 1}}, "noise: unknown key(s) jitter"),
    ("mvs_camera", {"noise": {"drop_probability": 2}}, "noise: jitter_px must be >= 0"),
    ("mvs_camera", {"calibration": {"skew": 1}}, "unknown calibration key 'skew'"),
    ("mvs_camera", {"rate_hz": 0}, "rate_hz: must be > 0"),
    ("mvs_camera", {"workpiece": "no_such_piece"}, "no_such_piece"),
    ("mvs_camera", {"exposure": 3}, "unknown key(s): exposure"),
    ("tool_sensor", {"serial": None}, "is missing 'serial'"),
    ("tool_sensor", {"tool_pose": None}, "is missing 'tool_pose'"),
    ("arm1", {"wcp": [0, 0, 0, 0, 0, "x"]}, "wcp must be 6 finite numbers"),
])
def test_device_options_are_checked(world_cell, device, change, message):
    raw = world_cell.world["devices"]
    table = dict(raw[device])
    for k, v in change.items():
        if v is None:
            table.pop(k)
        else:
            table[k] = v
    raw[device] = table
    with pytest.raises(BadInput) as exc:
        build_world(world_cell)
    assert message in str(exc.value)
    assert f"[world.devices.{device}]" in str(exc.value) or "no_such_piece" in message


# -- lockstep -----------------------------------------------------------------------

CAMERA = {"workpiece": "step_input", "tool_robot": "arm1", "holder_robot": "gmf1",
          "sensor_pose": SENSOR_POSE, "workpiece_mount": MOUNT,
          "noise": {"jitter_px": 0.5, "spurious_fraction": 0.02}}
TOOL = {"workpiece": "step_input", "tool_robot": "arm1", "holder_robot": "gmf1",
        "tool_pose": TOOL_POSE, "workpiece_mount": MOUNT}


def run_lockstep(seconds=2.0, seed=3, holder=None):
    arm, holder_dev, _ = rig(holder or holder_shifted(3.0, 1.0))
    sched = Scheduler(60.0)
    run = mvs_lockstep(sched, {"arm1": arm, "gmf1": holder_dev}, CAMERA, TOOL, seed=seed)
    try:
        sched.run_for(seconds)
    finally:
        run.close()
    return run, sched


def test_lockstep_chain_fills_both_status_records():
    t0 = time.perf_counter()
    run, sched = run_lockstep(2.0)
    mvs = run.mvs.status.read()
    assert not mvs["stale"] and mvs["homed"] == 0 and mvs["fault"] == 0
    assert mvs["y"] == pytest.approx(3.0, abs=0.6) and mvs["x"] == pytest.approx(1.0, abs=0.3)
    assert 110 <= mvs["valid_count"] <= 121 and mvs["garbled_count"] == 0
    assert mvs["tick"] in (sched.tick, sched.tick - 1)  # a line arrives about a tick after its frame
    tool = run.tool_chain.status.read()
    assert (tool["x"], tool["y"], tool["homed"], tool["stale"]) == (1.0, 3.0, 0, 0)
    assert run.camera.frames == run.sensor.frames == 121 and run.retrace_timeouts == 0
    assert time.perf_counter() - t0 < 30  # loose: virtual time never waits on a wall clock


def test_lockstep_is_deterministic_for_a_seed():
    a, _ = run_lockstep(1.0, seed=5)
    b, _ = run_lockstep(1.0, seed=5)
    c, _ = run_lockstep(1.0, seed=6)
    fields = ("x", "y", "R", "valid_count", "tick")
    ra, rb, rc = (r.mvs.status.read() for r in (a, b, c))
    assert all(np.array_equal(ra[f], rb[f]) for f in fields)
    assert not all(np.array_equal(ra[f], rc[f]) for f in ("x", "y", "R"))


def test_lockstep_dropped_frames_end_in_invalid_then_stale():
    arm, holder, _ = rig()
    sched = Scheduler(60.0)
    cam = dict(CAMERA, noise={"drop_probability": 1.0})
    run = mvs_lockstep(sched, {"arm1": arm, "gmf1": holder}, cam, seed=1)
    try:
        sched.run_for(1.0)
    finally:
        run.close()
    st = run.mvs.status.read()
    # droid-mvs sends 'invalid' every retrace timeout (0.1 s); the link stays fresh but invalid
    assert run.retrace_timeouts >= 8 and st["homed"] == 1 and st["valid_count"] == 0
    assert st["invalid_count"] >= 7


def test_lockstep_sensor_follows_a_moving_holder():
    """The camera reads the arms' poses at each frame: a holder that moves is seen."""
    class SlidingHolder(FixedArm):
        def __init__(self):
            super().__init__("gmf1", pose_to_T(*GMF1_WCP))
            self.y_mm = 0.0

        def wcp_global(self):
            T = super().wcp_global()
            T[1, 3] += self.y_mm
            return T

    arm = FixedArm("arm1", pose_to_T(*ARM1_WCP))
    holder = SlidingHolder()
    sched = Scheduler(60.0)
    sched.every(200.0, lambda t_ns: setattr(holder, "y_mm", 4.0 * t_ns / 1e9), "world", order=ORDER_WORLD)
    run = mvs_lockstep(sched, {"arm1": arm, "gmf1": holder}, CAMERA, TOOL, seed=2)
    try:
        sched.run_for(1.0)
    finally:
        run.close()
    assert run.mvs.status.read()["y"] == pytest.approx(4.0, abs=0.5)
    assert run.tool_chain.status.read()["y"] == pytest.approx(4.0, abs=0.2)
    assert math.isfinite(run.tool_chain.status.read()["x"])


def test_lockstep_ideal_sensor_reads_the_exact_geometry_and_agrees_with_the_camera():
    arm, holder, _ = rig(holder_shifted(3.0, 1.0))
    sched = Scheduler(60.0)
    run = mvs_lockstep(sched, {"arm1": arm, "gmf1": holder}, CAMERA, seed=1, ideal_sensor=True)
    try:
        sched.run_for(1.0)
    finally:
        run.close()
    st = run.mvs.status.read()
    assert (st["x"], st["y"], st["homed"], st["stale"]) == (1.0, 3.0, 0, 0)
    assert run.camera.frames == 0 and run.sensor.frames == 61  # nothing rendered
    camera_run, _ = run_lockstep(1.0, seed=1)  # the same layout through pixels and extraction
    cam = camera_run.mvs.status.read()
    assert (cam["x"], cam["y"]) == pytest.approx((1.0, 3.0), abs=0.6)


def test_ideal_sensor_is_invalid_outside_the_field_of_view():
    from droid.sim.mvs.devices import IdealSensorCore

    core = IdealSensorCore(STEP, MvsCalibration())
    assert core.step(pose_for_reading(STEP, 70.0, 2.0, 23.0)) == b"2.000,23.000,0.00000\n"
    assert core.step(pose_for_reading(STEP, 70.0, 0.0, 24.5)) == b"invalid\n"  # beyond +-23.9 mm
    assert core.step(pose_for_reading(STEP, 70.0, -26.0, 0.0)) == b"invalid\n"  # beyond +-25.55 mm
