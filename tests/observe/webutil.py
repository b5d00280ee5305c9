"""Start droid-web as a process for a test and wait until it listens; stop a server process;
hold a port so that a server finds it taken."""
from __future__ import annotations

import contextlib
import json
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request

from tests.brain.cellutil import ROOT, free_port


def stop_process(proc: subprocess.Popen, timeout_s: float) -> None:
    """SIGTERM ``proc`` if it still runs, SIGKILL if it has not exited within ``timeout_s``; reaped."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextlib.contextmanager
def taken_port():
    """A loopback TCP port a listening socket holds for the ``with`` block (yields the port)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


class WebServer:
    def __init__(self, *args: str) -> None:
        self.port = free_port()
        self.proc = subprocess.Popen([sys.executable, "-m", "droid.observe.web", "--port", str(self.port), *args],
                                     cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.url = f"http://127.0.0.1:{self.port}/"
        deadline = time.monotonic() + 60
        while True:
            if self.proc.poll() is not None:
                raise AssertionError(f"droid-web exited {self.proc.returncode}: {self.proc.stderr.read()}")
            try:
                self.get("api/cell")
                return
            except urllib.error.HTTPError:
                return  # listening (e.g. 401 without the token)
            except OSError:
                if time.monotonic() > deadline:
                    self.stop()
                    raise AssertionError("droid-web did not start listening")
                time.sleep(0.1)

    def get(self, path: str, token: str | None = None):
        req = urllib.request.Request(self.url + path)
        if token:
            req.add_header("Authorization", f"Bearer {token}")
        with urllib.request.urlopen(req, timeout=10) as r:
            return json.loads(r.read())

    def stop(self) -> int:
        stop_process(self.proc, 10)
        self.proc.stdout.close()
        self.proc.stderr.close()
        return self.proc.returncode

    def __enter__(self) -> "WebServer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def lockstep_recording(path) -> str:
    """A short lockstep trial recorded to ``path`` (fast: well under a second)."""
    from droid.experiments.matrix import resolve
    from droid.experiments.trial import run_trial, with_overrides

    cfg = with_overrides(resolve(["1.3"])[0].config, length_mm=60.0)
    run_trial(cfg, record=str(path))
    return str(path)




#: the guard recording's course: both arms of reis_pair.toml (arm2's base at 1800 mm, so their reaches
#: overlap) stretch toward each other from FROM_DEG to TO_DEG [deg] in COURSE_TICKS heartbeat ticks
GUARD_GAP_MM = 1800.0
GUARD_FROM_DEG = (0.0, 20.0, -10.0, 0.0, 0.0, 0.0)
GUARD_TO_DEG = (0.0, -60.0, 40.0, 0.0, 0.0, 0.0)
GUARD_COURSE_TICKS = 60


def guard_cell(run: bool = True):
    """reis_pair.toml with arm2's base at :data:`GUARD_GAP_MM` and ``[guard] run`` = ``run``."""
    from droid.brain.cell.cellfile import BUNDLED_CELLS, load_cell

    cell = load_cell(BUNDLED_CELLS / "reis_pair.toml")
    cell.subunits["arm2"].base = [GUARD_GAP_MM, *cell.subunits["arm2"].base[1:]]
    cell.raw["guard"] = dict(cell.raw["guard"], run=run)
    return cell


def guard_recording(path, run: bool = True) -> str:
    """A recording with the collision guard's Status (``/guard/status``), in the layout droid-record
    writes: droid-guard's station (droid.guard.station.GuardStation, the live program's) over the two
    arms' Status records as both stretch toward each other (:data:`GUARD_FROM_DEG` ->
    :data:`GUARD_TO_DEG`, then at rest for 20 ticks), so the guard goes clear -> slowing -> stopped.
    Pure: records in memory, virtual time; the arms are Status records, no planner moves them."""
    import numpy as np

    from droid.brain.db import layouts as L
    from droid.brain.db.shmdb import MemoryDatabase
    from droid.guard.station import GuardStation, guard_core
    from droid.kinematics import load_robot
    from droid.observe.mcapfile import RecordingWriter, cell_meta
    from droid.observe.record import CellRecorder
    from droid.observe.scene import scene_meta

    cell = guard_cell(run)
    core = guard_core(cell)
    arms, gearing = {}, {}
    for name in core.scene.arms:
        gearing[name] = load_robot(cell.subunits[name].robot).gearing
        arms[name] = (gearing[name], MemoryDatabase(f"{name}.status", L.ARM_STATUS_LAYOUT),
                      MemoryDatabase(f"{name}.ctrl_status", L.CTRL_STATUS_LAYOUT),
                      MemoryDatabase(f"{name}.command", L.ARM_COMMAND_LAYOUT))
    gdb = MemoryDatabase("guard.status", L.GUARD_STATUS_LAYOUT)
    station = GuardStation(core, arms, gdb, stale_ticks=6) if run else None
    rec = CellRecorder(RecordingWriter(str(path), cell_meta(cell, "lockstep", scene_meta(cell))))
    a, b = np.asarray(GUARD_FROM_DEG), np.asarray(GUARD_TO_DEG)
    period_ns = int(round(1e9 / cell.heartbeat_hz))
    for tick in range(1, GUARD_COURSE_TICKS + 22):
        s = min(1.0, (tick - 1) / GUARD_COURSE_TICKS)
        for name, (g, st, *_rest) in arms.items():
            counts = np.rint(g.joints_to_counts(a + s * (b - a)))
            st.update(encoder_pos=counts, encoder_cmd=counts, homed=1, tick=tick)
        if station is not None:
            station.on_tick(tick)
        recs = [(n, "status", L.ARM_STATUS_LAYOUT, st.read()) for n, (_, st, *_r) in arms.items()]
        recs.append(("guard", "status", L.GUARD_STATUS_LAYOUT, gdb.read()))
        rec.sample(tick, tick * period_ns, recs)
    rec.close()
    return str(path)
