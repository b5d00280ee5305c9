"""The joystick class (thesis §2.6 Figure 2.10, §3.4): layouts, driver, twin, jog core -- in process."""
from __future__ import annotations

import os
import struct

import numpy as np
import pytest

from droid.brain.runtime import cheader
from droid.brain.cell.cellfile import load_cell
from droid.brain.cell.registry import classes
from droid.brain.db.databases import brain_layouts, local_layouts
from droid.brain.db import layouts as L
from droid.brain.db.layouts import JOYSTICK_STATUS_LAYOUT, LAYOUTS, new_record
from droid.cli import BadInput
from droid.kinematics import load_robot
from droid.sim.joystick.device import JoystickDevice, JoystickTwin
from droid.subunits.joystick.driver import EvdevParser, JoystickState, JsParser, open_joystick
from droid.subunits.joystick.prog import joystick_options
from droid.subunits.joystick.station import JoystickStation, record_fields
from droid.tasks.snoop import status_dict, status_text
from droid.tasks.stick import BUTTON_MODE, BUTTON_QUIT, StickInput, StickJog

# written out here, independent of the driver's constants (linux/joystick.h, linux/input.h)
JS = "<IhBB"
EV = "<qqHHi"


def js(ms, value, typ, number):
    return struct.pack(JS, ms, value, typ, number)


def test_every_class_is_data_and_every_layout_is_known():
    for c in classes().values():
        assert "status" in c.brain and "ctrl_status" in c.local
        for lay in (*c.brain.values(), *c.local.values()):
            assert LAYOUTS[lay.kind] is lay
        rec = new_record(c.local["ctrl_status"])
        for f in c.copy_fields:
            assert f in rec.dtype.names, (c.name, f)
    assert "droid_joystick_status_t" in cheader.generate()


def test_default_cell_has_the_joystick_subunit():
    cell = load_cell()
    joy = cell.subunit("joy")
    assert joy.cls == "joystick" and not joy.is_arm
    assert brain_layouts(joy) == {"status": JOYSTICK_STATUS_LAYOUT}
    assert local_layouts(joy) == {"ctrl_status": JOYSTICK_STATUS_LAYOUT}
    url, rate = joystick_options(joy)
    assert url.startswith("js://") and url.endswith("/joy.js") and rate == 100.0
    assert cell.world["devices"]["joy_stick"]["device"] == url[len("js://"):]
    with pytest.raises(BadInput):
        joystick_options(cell.subunit("arm1"))


def test_js_parser_real_event_bytes_split_anywhere():
    st = JoystickState()
    p = JsParser(st)
    stream = (js(0, 0, 0x81, 0) + js(0, 1, 0x81, 5) + js(0, -32767, 0x82, 0) + js(0, 0, 0x82, 1)
              + js(120, 16384, 0x02, 1) + js(130, 0, 0x01, 5) + js(140, 5, 0x07, 0))
    got = sum(p.feed(stream[i:i + 5]) for i in range(0, len(stream), 5))
    assert got == 7
    assert st.axes[0] == -1.0 and st.axes[1] == pytest.approx(16384 / 32767)
    assert st.buttons[5] == 0 and st.n_axes == 2 and st.n_buttons == 6
    assert st.events == 6 and st.ignored == 1  # type 0x07 is not a joystick event
    p.feed(js(0, 1, 0x01, 40))  # a button beyond the record: counted, not stored
    assert st.ignored == 2 and sum(st.buttons) == 0


def test_evdev_parser_scales_by_the_axis_range():
    st = JoystickState()
    p = EvdevParser(st, {0: (0, 255)})
    data = (struct.pack(EV, 1, 0, 3, 0, 255) + struct.pack(EV, 1, 0, 3, 1, -32767)
            + struct.pack(EV, 1, 0, 1, 0x121, 1) + struct.pack(EV, 1, 0, 1, 0x131, 1)
            + struct.pack(EV, 1, 0, 0, 0, 0))
    assert p.feed(data) == 5
    assert st.axes[0] == 1.0 and st.axes[1] == -1.0
    assert st.buttons[1] == 1 and st.events == 4 and st.ignored == 0


@pytest.mark.parametrize("url", ["foo:///dev/input/js0", "js://", "js://host/dev/js0",
                                 "js:///dev/input/js0?min=1", "evdev:///dev/e?rate=3", "/dev/input/js0"])
def test_bad_device_urls_are_refused(url):
    with pytest.raises(BadInput):
        open_joystick(url)


def test_driver_reads_a_device_file_and_notices_it_vanish(tmp_path):
    path = tmp_path / "js0"
    os.mkfifo(path)
    dev = open_joystick(f"js://{path}")
    r0 = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # lets the writer open without blocking
    w = os.open(path, os.O_WRONLY)
    os.close(r0)
    assert dev.poll() == 0 and dev.state.valid  # opened; nothing written yet
    os.write(w, js(0, 32767, 0x82, 1) + js(5, 1, 0x01, 2) + js(9, 0, 0x02, 0)[:3])
    assert dev.poll() == 2
    assert dev.state.axes[1] == 1.0 and dev.state.buttons[2] == 1
    os.close(w)  # the writer goes away: end of file -> invalid, centred, released
    dev.poll()
    assert not dev.state.valid and dev.fd < 0 and dev.state.axes[1] == 0.0 and dev.state.buttons[2] == 0
    assert dev.poll() == 0 and dev.opens == 2  # reopened on the next poll
    dev.close()


def test_station_reads_every_cycle_and_retries_a_lost_device_every_reopen_cycles(tmp_path):
    """JoystickStation, the cycle droid-joystick's shell steps: a device that goes away reads
    centred and released with the DEVICE fault (one line), is tried again only every
    reopen_cycles cycles (counted in cycles, not seconds: lockstep steps it the same way),
    and reads again once it is back."""
    path = tmp_path / "js0"
    lines = []
    dev = open_joystick(f"js://{path}")
    st = JoystickStation(dev, 100.0, log=lines.append)
    assert st.reopen_cycles == 50 and st.reopen_s == 0.5
    f = st.start(1)
    assert f["valid"] == 0 and f["fault"] == L.FAULT_DEVICE and f["updated_ns"] == 1
    assert len(lines) == 1 and "retrying every 0.5 s" in lines[0] and str(path) in lines[0]
    os.mkfifo(path)
    r0 = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a reader until the station opens it
    w = os.open(path, os.O_WRONLY)
    os.write(w, js(0, 32767, 0x82, 1))
    for c in range(1, 50):  # the device is there now, but not tried before cycle 50
        assert st.cycle(c)["valid"] == 0 and dev.opens == 0
    f = st.cycle(50)
    assert dev.opens == 1 and f["valid"] == 1 and f["fault"] == 0 and f["axes"][1] == 1.0
    os.close(r0)
    os.write(w, js(0, -32767, 0x02, 1))
    assert st.cycle(51)["axes"][1] == -1.0  # open: read every cycle
    os.close(w)  # the writer goes away
    f = st.cycle(52)
    assert f["valid"] == 0 and f["axes"][1] == 0.0 and f["fault"] == L.FAULT_DEVICE
    assert len(lines) == 2 and lines[1].endswith("end of file; reopening")
    assert st.cycle(53)["valid"] == 0 and dev.opens == 1  # not retried at once
    dev.close()


def test_twin_core_round_trips_through_the_parser():
    twin = JoystickTwin(2, 8, script=[(0.5, [0.25, -1.0], [0, 0, 1, 0, 0, 0, 0, 0])], resync_s=10.0)
    st = JoystickState()
    p = JsParser(st)
    p.feed(twin.advance(0.01))  # the initial state: 8 buttons + 2 axes, flagged INIT
    assert st.n_axes == 2 and st.n_buttons == 8 and st.axes[:2] == [0.0, 0.0]
    for _ in range(60):
        p.feed(twin.advance(0.01))
    assert st.axes[0] == pytest.approx(0.25, abs=1e-4) and st.axes[1] == -1.0 and st.buttons[2] == 1
    n = st.events
    p.feed(twin.advance(0.01))  # nothing changed: nothing sent
    assert st.events == n


def test_twin_on_a_pty_is_read_by_the_real_driver(tmp_path):
    path = str(tmp_path / "joy.js")
    twin_dev = JoystickDevice("joy_stick", path, JoystickTwin(2, 8, resync_s=0.5))
    try:
        dev = open_joystick(f"js://{path}")
        twin_dev.advance(0.01)
        dev.poll()
        assert dev.state.valid and dev.state.n_axes == 2 and dev.state.n_buttons == 8
        twin_dev.twin.move([-0.5, 0.75], [1, 0, 0, 0, 0, 0, 0, 1])
        twin_dev.advance(0.01)
        dev.poll()
        assert dev.state.axes[0] == pytest.approx(-0.5, abs=1e-4)
        assert dev.state.axes[1] == pytest.approx(0.75, abs=1e-4)
        assert dev.state.buttons[0] == 1 and dev.state.buttons[7] == 1
        rec = new_record(JOYSTICK_STATUS_LAYOUT)
        for k, v in record_fields(dev, 7).items():
            rec[k] = v
        assert rec["valid"] == 1 and rec["fault"] == 0 and rec["axes"][1] == pytest.approx(0.75, abs=1e-4)
        assert rec["updated_ns"] == 7  # the caller's clock
    finally:
        twin_dev.close()
    dev.poll()  # the twin is gone: the pty hangs up
    assert not dev.state.valid and record_fields(dev, 8)["fault"] != 0
    dev.close()


def test_snoop_prints_axes_and_buttons():
    cell = load_cell()
    rec = new_record(JOYSTICK_STATUS_LAYOUT)
    rec["axes"][:2] = [0.5, -0.25]
    rec["buttons"][3] = 1
    rec["valid"] = 1
    rec["n_axes"], rec["n_buttons"] = 2, 8
    d = status_dict(cell.subunit("joy"), rec)
    assert d["axes"][:2] == [0.5, -0.25] and d["buttons"][3] == 1 and d["valid"] == 1
    assert "buttons [3]" in status_text(d)
    arm = status_dict(cell.subunit("arm1"), new_record(classes()["arm6r"].brain["status"]))
    assert list(arm) == ["subunit", "tick", "stale", "x", "y", "z", "R", "encoder_pos", "encoder_cmd",
                         "busy", "homed", "cmd_mode", "fault"]


# ---------------------------------------------------------------- the Joystick program's core


def stick(axes=(0.0, 0.0), buttons=(0,) * 8, valid=True, stale=False):
    return StickInput(tuple(axes), tuple(buttons), valid, stale)


def press(b):
    return tuple(1 if i == b else 0 for i in range(8))


@pytest.fixture(scope="module")
def reis():
    return load_robot("reis_v15")


def test_joint_mode_moves_at_the_deflected_speed_before_homing(reis):
    core = StickJog(reis, 60.0)
    total = np.zeros(6)
    for _ in range(60):  # one second at full deflection of axis 0
        act = core.step(1 / 60, stick((1.0, 0.0)), homed=False, delivered=True)
        if act.kind == "jog":
            total += act.delta_counts
    want = core._counts_per_s[0]
    assert abs(total[0] - want) <= 1.0 and not total[1:].any()


def test_no_motion_while_invalid_or_stale_and_nothing_lost_while_undelivered(reis):
    core = StickJog(reis, 60.0)
    for s in (stick((1.0, 1.0), valid=False), stick((1.0, 1.0), stale=True)):
        assert core.step(0.1, s, homed=True, delivered=True).kind == "none"
    assert core.step(0.5, stick((0.0, -1.0)), homed=False, delivered=False).kind == "none"
    act = core.step(0.5, stick((0.0, -1.0)), homed=False, delivered=True)
    assert act.kind == "jog" and abs(act.delta_counts[1] + core._counts_per_s[1]) <= 1.0
    assert core.step(1.0, stick((0.05, -0.05)), homed=False, delivered=True).kind == "none"  # dead band


def test_buttons_select_pairs_toggle_mode_and_quit(reis):
    core = StickJog(reis, 60.0)
    core.step(0.01, stick(buttons=press(2)), homed=False, delivered=True)
    act = core.step(1.0, stick((1.0, 0.0)), homed=False, delivered=True)
    assert act.kind == "jog" and act.delta_counts[4] != 0 and not act.delta_counts[:4].any()
    act = core.step(0.01, stick(buttons=press(BUTTON_MODE)), homed=False, delivered=True)
    assert core.cart and "cartesian" in act.note
    act = core.step(0.5, stick((1.0, 0.0)), homed=False, delivered=True)
    assert act.kind == "none" and "homed" in act.note  # cartesian needs a homed arm
    assert core.step(0.01, stick(buttons=press(BUTTON_QUIT)), homed=False, delivered=True).kind == "quit"


def test_cartesian_mode_moves_the_wrist_centre(reis):
    q = np.array([10.0, 10.0, 10.0, 0.0, 30.0, 0.0])
    core = StickJog(reis, 60.0, cart=True)
    act = None
    for _ in range(12):
        act = core.step(1 / 60, stick((1.0, 0.0)), homed=True, delivered=True, q_deg=q)
        if act.kind == "cart":
            break
    assert act.kind == "cart" and act.ticks == 6
    moved = act.T[:3, 3] - reis.fk(q)[:3, 3]
    assert moved[0] == pytest.approx(core.cart_mm_s * 0.1, rel=0.2)  # 50 mm/s for ~0.1 s
    assert abs(moved[1]) < 1e-6 and abs(moved[2]) < 1e-6


def test_the_class_table_names_the_drivers_the_url_table_opens():
    import importlib

    from droid.subunits.joystick.driver import DRIVERS

    table = classes()["joystick"].drivers
    assert set(table) == set(DRIVERS)
    for scheme, ref in table.items():
        module, name = ref.split(":")
        assert getattr(importlib.import_module(module), name) is DRIVERS[scheme]
