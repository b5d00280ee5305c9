"""The simulated MVS DSP board: the writer side of droid.subunits.mvs.dsp.

:class:`MvsDspTwin` is what droid-sim steps at 60 Hz: it renders a camera
frame for the sensor's pose and, unless the frame is dropped, writes it into
the board and signals the vertical retrace.  The board is chosen by the same
URL the sensor program is given (``shm://NAME`` or ``inproc://NAME``).

Run as a program it is a small stand-alone world for the sensor alone (tests,
demos): the sensor sweeps along a workpiece's seam at a fixed offset::

    python -m droid.sim.mvs.dsp shm://droid.demo.mvs.dsp --workpiece step_input \\
        --lateral 2 --speed 16

It prints ``ready`` on stdout once the board exists and removes it on
SIGINT/SIGTERM or after ``--count`` frames.
"""
from __future__ import annotations

import math
import mmap
import os
import signal
import sys
import time

import numpy as np
import posix_ipc

from droid.cli import ArgumentParser, BadInput, bounded_float, bounded_int, rate_hz, run, seed_int
from droid.sim.mvs.camera import CameraNoise, MvsCamera
from droid.sim.mvs.tool_sensor import pose_for_reading
from droid.sim.workpiece import load_workpiece
from droid.subunits.mvs.dsp import forget_inproc_channel, inproc_channel, parse_dsp_url
from droid.subunits.mvs.wire import (COLUMNS, DSP_LAYOUT_VERSION, DSP_MAGIC, DSP_RECORD,
                                     FRAME_RATE_HZ, RETRACE_SUFFIX, ROWS)


def _unlink_quietly(unlink, name: str) -> None:
    try:
        unlink(name)
    except posix_ipc.ExistentialError:
        pass


class ShmDspWriter:
    """Creates the shared-memory board ``/NAME`` + ``/NAME.retrace`` and writes frames.

    A board left behind by a dead writer is replaced (the board is recreated
    at start, as the cell does).
    """

    def __init__(self, name: str):
        self.name = name
        self._shm_name = "/" + name
        self._sem_name = self._shm_name + RETRACE_SUFFIX
        _unlink_quietly(posix_ipc.unlink_shared_memory, self._shm_name)
        _unlink_quietly(posix_ipc.unlink_semaphore, self._sem_name)
        shm = posix_ipc.SharedMemory(self._shm_name, posix_ipc.O_CREX, size=DSP_RECORD.itemsize)
        try:
            self._map = mmap.mmap(shm.fd, DSP_RECORD.itemsize)
        finally:
            shm.close_fd()
        self._rec = np.ndarray((), DSP_RECORD, buffer=self._map)
        self._rec["stripe"] = -1
        self._rec["writer_pid"] = os.getpid()
        self._rec["rows"], self._rec["columns"] = ROWS, COLUMNS
        self._rec["version"] = DSP_LAYOUT_VERSION
        self._rec["magic"] = DSP_MAGIC
        self._sem = posix_ipc.Semaphore(self._sem_name, posix_ipc.O_CREX, initial_value=0)

    @property
    def frames(self) -> int:
        return int(self._rec["frames"])

    def publish(self, rows: np.ndarray, timestamp_ns: int = 0) -> int:
        """Write one frame (seqlock) and post the retrace; returns the frame counter."""
        rec = self._rec
        rec["sequence"] += 1  # odd: writing
        rec["stripe"] = rows
        rec["frames"] += 1
        rec["timestamp_ns"] = timestamp_ns
        rec["sequence"] += 1  # even: whole
        if self._sem.value == 0:  # an event, not a counter of frames
            self._sem.release()
        return int(rec["frames"])

    def close(self) -> None:
        """Remove the board (shared memory and semaphore)."""
        if self._rec is None:
            return
        self._rec = None
        self._map.close()
        self._sem.close()
        _unlink_quietly(posix_ipc.unlink_shared_memory, self._shm_name)
        _unlink_quietly(posix_ipc.unlink_semaphore, self._sem_name)


class InprocDspWriter:
    """Writer of the in-process board ``inproc://NAME``."""

    def __init__(self, name: str):
        self.name = name
        self._channel = inproc_channel(name)

    @property
    def frames(self) -> int:
        return self._channel.frames

    def publish(self, rows: np.ndarray, timestamp_ns: int = 0) -> int:
        return self._channel.publish(rows)

    def close(self) -> None:
        forget_inproc_channel(self.name)


def open_dsp_writer(url: str) -> ShmDspWriter | InprocDspWriter:
    """Create the board named by a DSP URL (``shm://NAME`` or ``inproc://NAME``)."""
    scheme, name = parse_dsp_url(url)
    return ShmDspWriter(name) if scheme == "shm" else InprocDspWriter(name)


class MvsDspTwin:
    """Camera + DSP board, stepped once a video frame (60 Hz) by droid-sim."""

    def __init__(self, camera: MvsCamera, writer, seed: int = 0):
        self.camera = camera
        self.writer = writer
        self.rng = np.random.default_rng(seed)
        self.dropped = 0

    def step(self, T_W_S: np.ndarray, timestamp_ns: int = 0) -> np.ndarray | None:
        """Render the frame for the sensor pose T_W_S (4x4, mm) and deliver it.

        Returns the rows written, or None for a dropped frame (nothing is
        written and no retrace is signalled).
        """
        rows = self.camera.frame(T_W_S, self.rng)
        if rows is None:
            self.dropped += 1
            return None
        self.writer.publish(rows, timestamp_ns)
        return rows

    def close(self) -> None:
        self.writer.close()


@run
def main(argv=None) -> int:
    """A stand-alone DSP board sweeping along a workpiece (see the module docstring)."""
    parser = ArgumentParser(prog="droid-mvs-board", description=__doc__.split("\n\n")[0])
    parser.add_argument("url", help="board URL: shm://NAME")
    parser.add_argument("--workpiece", default="step_input", help="bundled name or TOML path")
    parser.add_argument("--start", type=bounded_float(-1e6, 1e6, "mm"), default=20.0, help="start arc length [mm]")
    parser.add_argument("--speed", type=bounded_float(-1e4, 1e4, "mm/s"), default=0.0, help="travel speed along the seam [mm/s]")
    parser.add_argument("--lateral", type=bounded_float(-1e3, 1e3, "mm"), default=0.0, help="feature y the sensor sees [mm]")
    parser.add_argument("--depth", type=bounded_float(-1e3, 1e3, "mm"), default=0.0, help="feature x the sensor sees [mm]")
    parser.add_argument("--roll", type=bounded_float(-90.0, 90.0, "deg"), default=0.0, help="surface roll the sensor sees [deg]")
    parser.add_argument("--jitter", type=bounded_float(0.0, 100.0, "px"), default=0.5, help="column jitter sigma [px]")
    parser.add_argument("--spurious", type=bounded_float(0.0, 1.0), default=0.0, help="fraction of spurious rows")
    parser.add_argument("--drop", type=bounded_float(0.0, 1.0), default=0.0, help="probability of a dropped frame")
    parser.add_argument("--rate", type=rate_hz(0.1, 1000.0), default=FRAME_RATE_HZ, help="frames per second")
    parser.add_argument("--count", type=bounded_int(1, 10**12, "frames"), help="stop after this many frames")
    parser.add_argument("--seed", type=seed_int, default=0, help="random seed of the camera noise (default 0)")
    args = parser.parse_args(argv)
    if parse_dsp_url(args.url)[0] != "shm":
        raise BadInput("a stand-alone board needs a shm://NAME URL")
    try:
        noise = CameraNoise(args.jitter, args.spurious, args.drop)
    except ValueError:
        raise BadInput("jitter must be >= 0, spurious and drop within [0, 1]") from None
    workpiece = load_workpiece(args.workpiece)
    twin = MvsDspTwin(MvsCamera(workpiece, noise=noise), open_dsp_writer(args.url), args.seed)
    stop = []
    handlers = {sig: signal.signal(sig, lambda *_: stop.append(1)) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        print("ready", flush=True)
        period = 1.0 / args.rate
        t0 = time.monotonic()
        n = 0
        while not stop and (args.count is None or n < args.count):
            s = args.start + args.speed * n * period
            pose = pose_for_reading(workpiece, s, args.depth, args.lateral, math.radians(args.roll))
            twin.step(pose, time.monotonic_ns())
            n += 1
            delay = t0 + n * period - time.monotonic()  # absolute deadlines, no drift
            if delay > 0:
                time.sleep(delay)
    finally:
        twin.close()
        for sig, old in handlers.items():
            signal.signal(sig, old)
    print(f"droid-mvs-board: {n} frames, {twin.dropped} dropped", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
