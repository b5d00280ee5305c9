"""droid-mvs's station (droid.subunits.mvs.station; issue 25 item 3): the per-frame cycle that
droid-mvs's real-time shell, the lockstep chain and the experiments' lead sensor all step --
the feature, the line, the retrace timeout counted in frame periods, the port's reopening.

No cell and no clock: the station is fed frames and waits as a shell would; the real-time
shell runs on a scripted board and port (its per-frame logic, not its timing)."""
from __future__ import annotations

import numpy as np
import pytest
import serial

from droid.brain.plumbing.sensor_line import parse_line
from droid.sim.lockstep import Scheduler
from droid.sim.mvs.camera import CameraNoise, MvsCamera
from droid.sim.mvs.tool_sensor import pose_for_reading
from droid.sim.workpiece import load_workpiece
from droid.subunits.mvs import sensor
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.dsp import DspFrame
from droid.subunits.mvs.station import RETRACE_TIMEOUT_FRAMES, MvsStation, SensorCore
from droid.subunits.mvs.wire import DEFAULT_BAUD, FRAME_RATE_HZ, ROWS

STEP = load_workpiece("step_input")
INVALID = b"invalid\n"
NO_STRIPE_FRAME = np.full(ROWS, -1, np.int16)


def frames(n: int, seed: int = 0) -> list[np.ndarray]:
    """n noisy frames of the step-input seam at offsets that change from frame to frame."""
    camera = MvsCamera(STEP, noise=CameraNoise(0.5, 0.02))
    rng = np.random.default_rng(seed)
    return [camera.frame(pose_for_reading(STEP, 60.0 + k, 0.1 * (k % 7), 0.5 * (k % 5) - 1.0), rng)
            for k in range(n)]


class FakePort:
    """A port with PortLink's manners: ``fail_writes`` (indices of write calls) raise and close it,
    ``timeout_writes`` time out with the port kept, ``failed_opens`` opens fail first."""

    def __init__(self, fail_writes=(), timeout_writes=(), failed_opens=0):
        self.is_open = True
        self.last_error = ""
        self.lines: list[bytes] = []
        self.writes = 0
        self.opens = 0
        self.fail_writes, self.timeout_writes, self.failed_opens = set(fail_writes), set(timeout_writes), failed_opens

    def open(self) -> bool:
        self.opens += 1
        if self.opens <= self.failed_opens:
            self.last_error = "no such port"
            return False
        self.is_open = True
        return True

    def write(self, data: bytes) -> bool:
        k = self.writes
        self.writes += 1
        if k in self.fail_writes:
            self.is_open, self.last_error = False, "the device hung up"
            return False
        if k in self.timeout_writes:
            return False
        self.lines.append(data)
        return True


def station(port=None, **kw) -> MvsStation:
    return MvsStation(SensorCore(MvsCalibration()), port, **kw)


# -- a frame ---------------------------------------------------------------------------------

def test_a_frame_is_its_line_sent_and_counted():
    port = FakePort()
    st = station(port)
    f = frames(1)[0]
    out = st.on_frame(f, missed=2)
    assert out.sent and out.line == port.lines[0] == SensorCore(MvsCalibration()).step(f)
    assert parse_line(out.line.rstrip(b"\n")).valid
    assert (st.core.frames, st.core.valid, st.missed, st.timeouts, st.stale) == (1, 1, 2, 0, False)
    assert st.on_frame(NO_STRIPE_FRAME).line == INVALID and st.core.invalid == 1  # a frame without a seam


def test_a_stamped_frame_carries_its_capture_ms_as_a_fourth_field():
    line = station().on_frame(frames(1)[0], stamp_ms=12345).line
    assert line.count(b",") == 3 and line.endswith(b",12345\n")
    assert parse_line(line.rstrip(b"\n")).valid


def test_without_a_port_the_caller_takes_the_line():
    out = station().on_frame(frames(1)[0])
    assert out.line is not None and not out.sent and out.port_error is None


# -- the timeout rule, in frame periods ------------------------------------------------------

def test_no_frame_for_a_whole_timeout_is_invalid_and_the_count_starts_again():
    st = station(FakePort())
    assert st.timeout_frames == RETRACE_TIMEOUT_FRAMES == 6
    lines = [st.on_wait(1).line for _ in range(13)]
    assert lines == [None] * 5 + [INVALID] + [None] * 5 + [INVALID] + [None]
    assert st.timeouts == 2 and st.stale and st.waited_frames == 1
    assert st.port.lines == [INVALID, INVALID]


def test_a_frame_inside_the_timeout_resets_the_count_and_the_stale_state():
    st = station()
    for _ in range(6):
        st.on_wait(1)
    assert st.stale and st.timeouts == 1
    for _ in range(5):
        assert st.on_wait(1).line is None
    assert parse_line(st.on_frame(frames(1)[0]).line.rstrip(b"\n")).valid
    assert not st.stale and st.waited_frames == 0
    assert [st.on_wait(1).line for _ in range(6)] == [None] * 5 + [INVALID]  # a whole timeout again


@pytest.mark.parametrize("timeout_s", [0.1, 0.05, 0.07, 1 / 60, 0.3, 2.5, 62 / 60, 2.05])  # x 60: 62.00..01, 122.99..99
def test_a_timeout_given_in_seconds_fires_on_its_whole_frame_count(timeout_s):
    """droid-mvs converts --retrace-timeout S to S x 60 frame periods and reports a timed-out wait as
    exactly that: always 'invalid'.  Lockstep's whole slots fire on the first count reaching it,
    float noise of S x 60 (62/60 s x 60 = 62.00000000000001) included, as the old rule in ns did."""
    frames_ = timeout_s * FRAME_RATE_HZ
    assert station(timeout_frames=frames_).on_wait(frames_).line == INVALID
    st = station(timeout_frames=frames_)
    slots = [st.on_wait(1).line for _ in range(int(np.ceil(frames_ - 1e-9)))]
    assert slots[-1] == INVALID and all(line is None for line in slots[:-1])


@pytest.mark.parametrize("bad", [0, -1.0, float("nan")])
def test_a_timeout_must_be_positive(bad):
    with pytest.raises(ValueError):
        station(timeout_frames=bad)


# -- the reopen rule -------------------------------------------------------------------------

def test_a_write_that_times_out_is_an_overrun_not_a_port_failure():
    port = FakePort(timeout_writes={0})
    st = station(port)
    out = st.on_frame(frames(1)[0])
    assert not out.sent and out.port_error is None and not out.fatal and port.is_open and st.lost == 0


def test_a_failed_port_ends_a_run_that_does_not_reopen():
    port = FakePort(fail_writes={1})
    st = station(port)
    f = frames(2)
    assert st.on_frame(f[0]).sent
    out = st.on_frame(f[1])
    assert out.fatal and out.port_error == "the device hung up" and not port.is_open and st.lost == 1


def test_a_failed_port_is_reopened_one_try_a_line_and_the_lost_lines_counted():
    port = FakePort(fail_writes={1}, failed_opens=2)
    st = station(port, reopen=True)
    f = frames(6)
    assert st.on_frame(f[0]).sent
    out = st.on_frame(f[1])  # the port fails: this line is lost
    assert out.port_error == "the device hung up" and not out.fatal and not port.is_open
    for k in (2, 3):  # one try a line, both fail: lost, no write
        out = st.on_frame(f[k])
        assert not out.sent and out.port_error is None and port.writes == 2
    out = st.on_frame(f[4])  # the third try opens it: the line goes out
    assert out.sent and port.is_open
    assert (st.reopen_attempts, st.reopened, st.lost) == (3, 1, 3)
    assert port.lines == [SensorCore(MvsCalibration()).step(f[k]) for k in (0, 4)]
    assert st.on_wait(RETRACE_TIMEOUT_FRAMES).sent  # a timeout's line takes the same way


# -- droid-mvs's shell on a scripted board and port (its per-frame logic, not its timing) -------

class ScriptBoard:
    """The DSP board on a virtual clock of frame slots (slot k at k frame periods): a wait of T s
    returns the first frame within T x 60 slots of the last event, or times out after exactly that."""

    def __init__(self, slots):
        self.slots, self.now, self.next = slots, 0.0, 0

    def wait_frame(self, timeout_s):
        end = self.now + timeout_s * FRAME_RATE_HZ
        while self.next < len(self.slots) and self.next <= end + 1e-9:
            k = self.next
            self.next += 1
            if self.slots[k] is not None:
                self.now = float(k)
                return DspFrame(k, self.slots[k], 0)
        self.now = end
        return None

    def close(self):
        pass


class FakeSerial:
    """What pyserial hands PortLink: the written lines are kept; the writes in ``fail`` hang up."""

    def __init__(self, lines, fail=()):
        self.lines, self.fail = lines, fail

    def reset_input_buffer(self):
        pass

    def write(self, data):
        if len(self.lines) in self.fail:
            self.fail = set(self.fail) - {len(self.lines)}
            self.lines.append(None)  # the line the port lost
            raise serial.SerialException("the device hung up")
        self.lines.append(bytes(data))

    def close(self):
        pass


def scripted_devices(monkeypatch, slots, fail=(), failed_opens=0):
    """droid-mvs's drivers replaced by the script's board and a recording port."""
    lines: list[bytes | None] = []
    opens = {"n": 0}

    def opener():
        opens["n"] += 1
        if opens["n"] > 1 and opens["n"] <= 1 + failed_opens:
            raise serial.SerialException("no such port")
        return FakeSerial(lines, fail)

    def open_url(url, kind, **options):
        return ScriptBoard(slots) if kind == "dsp" else opener

    monkeypatch.setattr(sensor, "open_url", open_url)
    return lines


def test_realtime_stand_alone_ends_on_a_failed_port_with_the_one_line_reason(monkeypatch, capsys):
    scripted_devices(monkeypatch, frames(5), fail={2})
    assert sensor.main(["--dsp", "inproc://script", "--serial", "loop://", "--count", "5",
                        "--board-wait", "0"]) == 1
    err = capsys.readouterr().err
    assert err == "droid-mvs: serial loop://: the device hung up\n"


def test_realtime_in_a_cell_reopens_the_port_and_reports_the_lost_lines(monkeypatch, capsys):
    slots = frames(8)
    lines = scripted_devices(monkeypatch, slots, fail={2}, failed_opens=2)
    args = sensor.build_parser().parse_args(["--dsp", "inproc://script", "--serial", "loop://", "--count", "8"])
    args.baud, args.board_wait = DEFAULT_BAUD, 0.0
    beats = []
    assert sensor.live(args, SensorCore(MvsCalibration()), beat=lambda n, over: beats.append((n, over)),
                       reopen=True) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "droid-mvs: serial loop://: the device hung up; reopening"
    assert "8 frames in" in err[1] and ", 3 lines lost with the port, 1 reopens)" in err[1]
    core = SensorCore(MvsCalibration())
    expected = [core.step(f) for f in slots]
    # the third line lost with the port, the fourth and fifth with the two opens that failed
    assert lines == expected[:2] + [None] + expected[5:]
    assert beats[-1] == (8, 3)


# -- the real-time shell's per-frame logic and lockstep agree --------------------------------

#: After the k-th frame of the script, this many empty slots (0: before the first).
GAPS = {3: 5, 5: 6, 7: 13, 9: 12, 10: 1, 12: 18}


def script(first_gap: int, seed: int = 4) -> list[np.ndarray | None]:
    """Frame slots at 60 Hz: a frame or None (no frame in that slot); 15 frames, ending on one."""
    f = iter(frames(30, seed))
    gaps = {0: first_gap, **GAPS}
    slots: list[np.ndarray | None] = [None] * gaps[0]
    for k in range(1, 16):
        slots.append(next(f))
        slots += [None] * gaps.get(k, 0)
    return slots


def realtime_lines(monkeypatch, slots) -> list[bytes]:
    lines = scripted_devices(monkeypatch, slots)
    count = sum(s is not None for s in slots)
    assert sensor.main(["--dsp", "inproc://script", "--serial", "loop://", "--count", str(count),
                        "--board-wait", "0"]) == 0
    return lines


def lockstep_lines(slots) -> list[bytes]:
    from droid.sim.mvs.lockstep import mvs_lockstep
    from tests.mvs.test_mvs_world_devices import CAMERA, rig

    class ScriptCamera:  # the camera twin's renderer, replaced by the script (None: a dropped frame)
        def __init__(self):
            self.k = 0

        def frame(self, T_W_S, rng):
            self.k += 1
            return slots[self.k - 1]

    arm, holder, _ = rig()
    sched = Scheduler(60.0)
    run = mvs_lockstep(sched, {"arm1": arm, "gmf1": holder}, CAMERA, seed=1)
    run.camera.twin.camera = ScriptCamera()
    lines: list[bytes] = []
    write = run.mvs.pipe.write
    run.mvs.pipe.write = lambda data, t_ns: lines.append(data) or write(data, t_ns)
    try:
        sched.run_until(round((len(slots) - 1) * 1e9 / 60.0))
    finally:
        run.close()
    assert run.camera.twin.camera.k == len(slots)
    return lines


@pytest.mark.parametrize("first_gap,first_timeouts", [(6, 0), (7, 1), (13, 2)])
def test_realtime_shell_and_lockstep_send_the_same_lines_for_the_same_frames(monkeypatch, capsys, first_gap,
                                                                              first_timeouts):
    """Both wait from their start: a first frame on the 7th slot (t = 0.1 s) still comes in time."""
    slots = script(first_gap)
    rt = realtime_lines(monkeypatch, slots)
    ls = lockstep_lines(slots)
    assert rt == ls
    # the gaps after it: 5 (the frame on the 6th slot comes in time), 6, 13, 12, 1, 18 slots
    timeouts = first_timeouts + 0 + 1 + 2 + 2 + 0 + 3
    assert rt.count(INVALID) == timeouts and len(rt) == 15 + timeouts
    err = capsys.readouterr().err
    assert "15 frames in" in err and f"{timeouts} retrace timeouts" in err and "0 serial overruns" in err


# -- the experiments' lead sensor ------------------------------------------------------------

def test_lead_sensor_dropped_frames_bring_no_line_until_the_timeout():
    from droid.sim.mvs.trial_sensors import LeadSensor

    lead = LeadSensor(STEP, "camera", CameraNoise(0.5, 0.0, drop_probability=1.0), frames_per_read=2)
    T = pose_for_reading(STEP, 60.0)
    got = [lead.read(T) for _ in range(7)]
    assert got[:2] == [None, None] and got[3:5] == [None, None] and got[6] is None
    assert not got[2].valid and not got[5].valid  # 'invalid' every 6 frame periods = 3 reads
    assert (lead.frames, lead.valid, lead.station.timeouts) == (7, 0, 2)
    ok = LeadSensor(STEP, "camera", CameraNoise(0.5, 0.0), frames_per_read=2).read(T)
    assert ok.valid and ok.y_mm == pytest.approx(0.0, abs=0.3)
