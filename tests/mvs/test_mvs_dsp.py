"""DSP board drivers (reader) and the simulated board (writer): shm and in-process."""
from __future__ import annotations

import os
import subprocess
import sys
import threading

import numpy as np
import posix_ipc
import pytest

from droid.cli import BadInput, RuntimeFailure
from droid.sim.mvs.camera import MvsCamera
from droid.sim.mvs.dsp import MvsDspTwin, ShmDspWriter, open_dsp_writer
from droid.sim.mvs.tool_sensor import pose_for_reading
from droid.sim.workpiece import load_workpiece
from droid.subunits.mvs.dsp import open_dsp, parse_dsp_url
from droid.subunits.mvs.wire import DSP_RECORD, ROWS

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def frame(value: int) -> np.ndarray:
    return np.full(ROWS, value, np.int16)


@pytest.fixture
def board_name(cell_name):
    return f"droid.{cell_name}.mvs.dsp"


def test_shm_frames_and_retrace_pass_between_two_objects(board_name):
    writer = ShmDspWriter(board_name)
    try:
        with open_dsp(f"shm://{board_name}") as reader:
            assert reader.writer_pid == os.getpid()
            assert reader.wait_frame(0.01) is None  # no retrace yet: timeout
            writer.publish(frame(7))
            got = reader.wait_frame(1.0)
            assert got.frame == 1 and got.missed == 0 and (got.rows == 7).all()
            assert got.rows.dtype == np.int16
            for v in (8, 9, 10):
                writer.publish(frame(v))
            got = reader.wait_frame(1.0)
            assert got.frame == 4 and got.missed == 2 and (got.rows == 10).all()
            assert reader.wait_frame(0.01) is None  # the extra retraces were drained
            got.rows[:] = 0  # a private copy
            writer.publish(frame(11))
            assert (reader.wait_frame(1.0).rows == 11).all()
    finally:
        writer.close()
    assert not os.path.exists(f"/dev/shm/{board_name}")
    assert not os.path.exists(f"/dev/shm/sem.{board_name}.retrace")


def test_retrace_semaphore_is_an_event_not_a_counter(board_name):
    writer = ShmDspWriter(board_name)
    try:
        for _ in range(50):
            writer.publish(frame(1))
        assert posix_ipc.Semaphore(f"/{board_name}.retrace").value == 1
    finally:
        writer.close()


def test_torn_frame_is_not_returned(board_name):
    writer = ShmDspWriter(board_name)
    try:
        with open_dsp(f"shm://{board_name}") as reader:
            writer.publish(frame(3))
            writer._rec["sequence"] += 1  # the writer "died" mid-copy: sequence stays odd
            assert reader.wait_frame(0.5) is None
    finally:
        writer.close()


def test_a_new_writer_replaces_a_stale_board(board_name):
    stale = ShmDspWriter(board_name)
    stale._rec["magic"] = 0
    fresh = ShmDspWriter(board_name)  # the cell recreates the board at start
    try:
        with open_dsp(f"shm://{board_name}") as reader:
            fresh.publish(frame(5))
            assert (reader.wait_frame(1.0).rows == 5).all()
    finally:
        stale._rec = None
        stale._map.close()
        stale._sem.close()
        fresh.close()


def test_absent_board_is_a_runtime_failure(board_name):
    with pytest.raises(RuntimeFailure, match="not present"):
        open_dsp(f"shm://{board_name}")
    with pytest.raises(RuntimeFailure, match="not present"):
        open_dsp(f"shm://{board_name}", wait_s=0.1)


def test_foreign_shared_memory_is_refused(board_name):
    shm = posix_ipc.SharedMemory(f"/{board_name}", posix_ipc.O_CREX, size=DSP_RECORD.itemsize)
    sem = posix_ipc.Semaphore(f"/{board_name}.retrace", posix_ipc.O_CREX)
    try:
        with pytest.raises(RuntimeFailure, match="not an MVS frame buffer"):
            open_dsp(f"shm://{board_name}")
    finally:
        shm.close_fd()
        shm.unlink()
        sem.unlink()
        sem.close()


@pytest.mark.parametrize("url,message", [
    ("tcp://x", "unknown scheme"), ("shm://", "NAME must be"), ("shm://a b", "NAME must be"),
    ("shm://droid.x?rate=60", "takes no options"), ("droid.x", "unknown scheme"),
])
def test_bad_urls_name_the_expected_form(url, message):
    with pytest.raises(BadInput, match=message) as err:
        parse_dsp_url(url)
    assert "shm://NAME or inproc://NAME" in str(err.value)


def test_inproc_board_between_two_objects_and_threads(cell_name):
    url = f"inproc://{cell_name}"
    writer = open_dsp_writer(url)
    try:
        reader = open_dsp(url)
        assert reader.wait_frame(0.0) is None
        writer.publish(frame(1))
        writer.publish(frame(2))
        got = reader.wait_frame(0.0)
        assert (got.frame, got.missed, int(got.rows[0])) == (2, 1, 2)
        publisher = threading.Timer(0.05, writer.publish, args=(frame(3),))
        publisher.start()
        got = reader.wait_frame(5.0)  # wakes on the retrace from the other thread
        publisher.join()
        assert (got.frame, int(got.rows[0])) == (3, 3)
    finally:
        writer.close()


def test_twin_renders_delivers_and_drops(cell_name):
    from droid.sim.mvs.camera import CameraNoise

    wp = load_workpiece("step_input")
    url = f"inproc://{cell_name}"
    pose = pose_for_reading(wp, 50.0, 1.0, 2.0, 0.0)
    twin = MvsDspTwin(MvsCamera(wp), open_dsp_writer(url), seed=3)
    reader = open_dsp(url)
    try:
        rows = twin.step(pose)
        got = reader.wait_frame(0.0)
        assert np.array_equal(got.rows, rows)
        assert np.array_equal(rows, MvsCamera(wp).frame(pose, np.random.default_rng(0)))  # noise-free
        twin.camera = MvsCamera(wp, noise=CameraNoise(drop_probability=1.0))
        assert twin.step(pose) is None and twin.dropped == 1
        assert reader.wait_frame(0.0) is None  # a dropped frame signals no retrace
    finally:
        twin.close()


def test_board_in_another_process(board_name):
    """A writer subprocess (the stand-alone board) and this process's reader."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "droid.sim.mvs.dsp", f"shm://{board_name}", "--jitter", "0",
         "--lateral", "2.0", "--rate", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
        env={**os.environ, "PYTHONPATH": REPO})
    try:
        assert proc.stdout.readline().strip() == "ready"
        wp = load_workpiece("step_input")
        expected = MvsCamera(wp).frame(pose_for_reading(wp, 20.0, 0.0, 2.0, 0.0), np.random.default_rng(0))
        with open_dsp(f"shm://{board_name}", wait_s=5.0) as reader:
            counters = []
            for _ in range(5):
                got = reader.wait_frame(5.0)
                assert got is not None and np.array_equal(got.rows, expected)
                counters.append(got.frame)
            assert reader.writer_pid == proc.pid
        assert counters == sorted(counters) and len(set(counters)) == 5
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "frames" in err
    assert not os.path.exists(f"/dev/shm/{board_name}")


def test_reader_follows_a_recreated_board(board_name):
    first = ShmDspWriter(board_name)
    try:
        with open_dsp(f"shm://{board_name}") as reader:
            first.publish(frame(1))
            assert (reader.wait_frame(1.0).rows == 1).all()
            first.close()  # droid-sim exits ...
            second = ShmDspWriter(board_name)  # ... and starts again
            try:
                assert reader.wait_frame(0.01) is None  # the timeout notices the new board
                second.publish(frame(2))
                got = reader.wait_frame(1.0)
                assert (got.rows == 2).all() and got.frame == 1
            finally:
                second.close()
    finally:
        first.close()
