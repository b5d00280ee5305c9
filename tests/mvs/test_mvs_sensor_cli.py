"""droid-mvs: replay mode, live mode over a pty, signals and bad input."""
from __future__ import annotations

import io
import os
import select
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from droid.sim.mvs.camera import CameraNoise, MvsCamera
from droid.sim.mvs.tool_sensor import pose_for_reading
from droid.sim.workpiece import load_workpiece
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.protocol import SensorClientCore, parse_line
from droid.subunits.mvs.sensor import SensorCore, format_frame_line, main
from tests.brain.cellutil import reaped

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ENV = {**os.environ, "PYTHONPATH": REPO}
STEP = load_workpiece("step_input")
TRUTH = [(1.0, 2.0, 0.05), (-3.0, -6.0, -0.1), (4.0, 10.0, 0.0)]


def recorded_frames(seed=0):
    camera = MvsCamera(STEP, noise=CameraNoise(0.5))
    rng = np.random.default_rng(seed)
    return [camera.frame(pose_for_reading(STEP, 200.0, *t), rng) for t in TRUTH]


def write_replay(path, frames, extra=()):
    lines = ["# recorded by test", ""] + [format_frame_line(f) for f in frames] + list(extra)
    path.write_text("\n".join(lines) + "\n")


def test_replay_prints_one_result_a_frame(tmp_path, capsys):
    path = tmp_path / "frames.txt"
    write_replay(path, recorded_frames(), extra=[" ".join(["-1"] * 240)])
    assert main(["--replay", str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 4 and out[3] == "invalid"
    for line, (x, y, roll) in zip(out[:3], TRUTH):
        r = parse_line(line.encode())
        assert r.valid and (r.x_mm, r.y_mm, r.roll_rad) == pytest.approx((x, y, roll), abs=0.15)


def test_replay_pixels_from_stdin(monkeypatch, capsys):
    frames = recorded_frames()
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n".join(format_frame_line(f) for f in frames) + "\n"))
    assert main(["--replay", "-", "--pixels"]) == 0
    cal = MvsCalibration()
    for line, (x, y, _) in zip(capsys.readouterr().out.splitlines(), TRUTH):
        row, col = map(float, line.split(","))
        assert (row, col) == pytest.approx((cal.row_of(y), cal.column_of(x)), abs=0.75)


@pytest.mark.parametrize("bad,message", [
    ("1 2 3", "frames.txt:4: expected 240 integers, got 3"),
    (" ".join(["10"] * 239 + ["x1"]), "frames.txt:4: not an integer: 'x1'"),
    (" ".join(["10"] * 239 + ["2.5"]), "frames.txt:4: not an integer: '2.5'"),
    (" ".join(["10"] * 239 + ["512"]), "frames.txt:4: column 512 beyond 511"),
])
def test_replay_bad_line_is_one_line_error_exit_2(tmp_path, capsys, bad, message):
    path = tmp_path / "frames.txt"
    path.write_text("# header\n\n" + format_frame_line(recorded_frames()[0]) + "\n" + bad + "\n")
    assert main(["--replay", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.out.count("\n") == 1  # the good frame before it was processed
    err = captured.err.strip()
    assert message in err and "\n" not in err


def test_replay_as_a_console_program(tmp_path):
    path = tmp_path / "frames.txt"
    write_replay(path, recorded_frames(), extra=["1 2"])
    proc = subprocess.run([sys.executable, "-m", "droid.subunits.mvs.sensor", "--replay", str(path)],
                          capture_output=True, text=True, env=ENV, cwd=REPO, timeout=30)
    assert proc.returncode == 2
    assert len(proc.stdout.splitlines()) == 3
    assert proc.stderr.count("\n") == 1 and "expected 240 integers" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("argv,message", [
    (["--dsp", "shm://droid.x.mvs.dsp"], "needs --dsp URL and --serial URL"),
    (["--pixels"], "--pixels needs --replay"),
    (["--replay", "-", "--count", "3"], "--replay takes no"),
    (["--replay", "/no/such/file"], "cannot open /no/such/file"),
    (["--dsp", "tcp://x", "--serial", "loop://"], "unknown scheme"),
])
def test_bad_arguments_exit_2(capsys, argv, message):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


@pytest.mark.parametrize("argv", [["--count", "0"], ["--baud", "fast"], ["--frobnicate"],
                                  ["--dsp", "shm://droid.x.mvs.dsp", "--serial", "loop://", "--baud", "9600"]])
def test_malformed_options_exit_2_with_one_line(capsys, argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    if "--baud" in argv and "9600" in argv:
        assert "[19200, 4000000] baud" in err, err


def test_bad_calibration_file_exit_2(tmp_path, capsys):
    path = tmp_path / "cal.toml"
    path.write_text("[calibration]\nlateral_mm_per_row = 0.25\nskew = 1\n")
    assert main(["--replay", "-", "--calib", str(path)]) == 2
    assert "unknown calibration key 'skew'" in capsys.readouterr().err


def test_calibration_file_changes_the_mm(tmp_path, capsys, monkeypatch):
    path = tmp_path / "cal.toml"
    path.write_text("[calibration]\nlateral_mm_per_row = 0.4\ndepth_mm_per_column = 0.2\n")
    frames = recorded_frames()
    monkeypatch.setattr(sys, "stdin", io.StringIO(format_frame_line(frames[0]) + "\n"))
    assert main(["--replay", "-", "--calib", str(path)]) == 0
    r = parse_line(capsys.readouterr().out.strip().encode())
    assert (r.x_mm, r.y_mm) == pytest.approx((2 * TRUTH[0][0], 2 * TRUTH[0][1]), abs=0.3)


def test_absent_board_is_exit_1(cell_name, capsys):
    assert main(["--dsp", f"shm://droid.{cell_name}.mvs.dsp", "--serial", "loop://", "--board-wait", "0"]) == 1
    assert "not present" in capsys.readouterr().err


def test_sensor_core_counts_and_formats():
    core = SensorCore(MvsCalibration())
    frames = recorded_frames()
    assert parse_line(core.step(frames[0])).valid
    assert core.step(np.full(240, -1, np.int16)) == b"invalid\n"
    assert (core.frames, core.valid, core.invalid) == (2, 1, 1)


@pytest.fixture
def board(cell_name):
    """A stand-alone simulated board in a subprocess, sensor seeing (x, y) = (1, 3) mm."""
    name = f"droid.{cell_name}.mvs.dsp"
    proc = subprocess.Popen(
        [sys.executable, "-m", "droid.sim.mvs.dsp", f"shm://{name}", "--lateral", "3", "--depth", "1",
         "--spurious", "0.05", "--speed", "16"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env=ENV)
    try:
        assert proc.stdout.readline().strip() == "ready"
        yield f"shm://{name}"
    finally:
        proc.terminate()
        proc.communicate(timeout=10)


def read_pty(fd, until_lines, timeout_s=20.0):
    data = b""
    deadline = time.monotonic() + timeout_s
    while data.count(b"\n") < until_lines and time.monotonic() < deadline:
        if select.select([fd], [], [], 0.2)[0]:
            data += os.read(fd, 4096)
    return data


def test_live_sensor_writes_lines_to_a_pty(board, tmp_path, capsys):
    master, slave = os.openpty()
    try:
        record = tmp_path / "rec.txt"
        assert main(["--dsp", board, "--serial", os.ttyname(slave), "--count", "20",
                     "--record", str(record)]) == 0
        data = read_pty(master, 20)
    finally:
        os.close(master)
        os.close(slave)
    client = SensorClientCore()
    newest = client.feed(data)
    assert client.lines == 20 and client.garbled == 0 and client.valid >= 18
    assert (newest.x_mm, newest.y_mm) == pytest.approx((1.0, 3.0), abs=0.3)
    err = capsys.readouterr().err
    assert "20 frames in" in err and "frames/s" in err
    # The recording replays to the same lines.
    assert main(["--replay", str(record)]) == 0
    replayed = capsys.readouterr().out.encode()
    assert replayed == data.replace(b"\r", b"")


def test_live_sensor_stops_cleanly_on_sigterm(board):
    master, slave = os.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "droid.subunits.mvs.sensor", "--dsp", board, "--serial", os.ttyname(slave)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env=ENV)
    try:
        with reaped(proc):
            data = read_pty(master, 5)
            assert data.count(b"\n") >= 5
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=10)
    finally:
        os.close(master)
        os.close(slave)
    assert proc.returncode == 0, err
    assert "frames/s" in err and "Traceback" not in err
