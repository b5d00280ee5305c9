"""Helpers for tests that bring a real cell of processes up on loopback."""
from __future__ import annotations

import contextlib
import json
import re
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

from droid.brain.cell.cellfile import builtin_cell_path, without_table

ROOT = Path(__file__).resolve().parents[2]


def make_cell_file(tmp_path: Path, name: str, source: Path | None = None, extra: str = "") -> Path:
    """A copy of a cell file (default: the built-in sim cell) renamed to ``name``, run dir in tmp."""
    text = (source or builtin_cell_path()).read_text()
    text = re.sub(r'(?m)^name = "[^"]*"', f'name = "{name}"\nrun_dir = "{tmp_path}/run"', text, count=1)
    path = tmp_path / f"{name}.toml"
    path.write_text(text + extra)
    return path


@contextlib.contextmanager
def brought_down(path: Path, cell_name: str):
    """Whatever the body does with the cell file ``path``, bring the cell down after it and
    check that ``down`` succeeds and leaves nothing of the cell in /dev/shm."""
    from droid.brain.db.shmdb import cell_objects

    try:
        yield path
    finally:
        out = droid("droid.brain.runtime.launcher", "down", "--cell", str(path))
        assert out.returncode == 0, out.stderr
        assert cell_objects(cell_name) == []


@contextlib.contextmanager
def cell_up(path: Path, cell_name: str):
    """Bring the cell file ``path`` up for the body and always down after it (:func:`brought_down`)."""
    with brought_down(path, cell_name):
        out = droid("droid.brain.runtime.launcher", "up", "--cell", str(path), timeout=120)
        assert out.returncode == 0, out.stdout + out.stderr
        yield path


@contextlib.contextmanager
def reaped(proc: subprocess.Popen):
    """The body works with the running ``proc``, which does not outlive it: killed and reaped
    if it still runs when the body ends (a failed assertion, a timeout)."""
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def droid(prog_module: str, *args: str, timeout: float = 60, check: bool = False) -> subprocess.CompletedProcess:
    """Run a DROID program as ``python -m MODULE ARGS``."""
    out = subprocess.run([sys.executable, "-m", prog_module, *args], capture_output=True, text=True,
                         timeout=timeout, cwd=ROOT)
    if check and out.returncode != 0:
        raise AssertionError(f"{prog_module} {args} -> {out.returncode}\n{out.stdout}\n{out.stderr}")
    return out


def in_process(main, capsys, *args: str) -> SimpleNamespace:
    """A program's ``main(args)`` called in this process, as ``droid()``'s ``returncode``, ``stdout``,
    ``stderr`` (from pytest's ``capsys``): for refusals that a program gives before it starts
    anything, where each ``python -m`` would only add an interpreter's start (keep at least one
    test of each program that runs it as a program)."""
    try:
        code = main(list(args))
    except SystemExit as exc:  # argparse's own exits (usage errors, --help)
        code = exc.code
    out = capsys.readouterr()
    return SimpleNamespace(returncode=code, stdout=out.out, stderr=out.err)


def cell_status(cell_file: Path) -> list[dict]:
    out = droid("droid.brain.runtime.launcher", "status", "--json", "--cell", str(cell_file))
    return [json.loads(line) for line in out.stdout.splitlines() if line.strip()]


def wait_for(pred, timeout: float = 20.0, interval: float = 0.1, what: str = "condition"):
    """Poll ``pred()`` until truthy; returns its value (a wait, not a timing verdict)."""
    deadline = time.monotonic() + timeout
    while True:
        val = pred()
        if val:
            return val
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(interval)


def stationary_reis(text: str, wcp=(300.0, 100.0, 1340.0, 0.0, 180.0, 0.0)) -> str:
    """A cell file text whose Reis is a fixed wrist-centre twin (at ``wcp``: x y z mm,
    ZYZ deg) run by its agent alone (no servo to drive it): a stationary arm."""
    reis = '[world.devices.arm1]\ntype = "reis_vme"\nsubunit = "arm1"\n'
    assert text.count(reis) == 1
    if "[world.devices.touch]" in text:  # a fixed twin has no plant for the workpiece to push on
        text = without_table(text, "[world.devices.touch]")
    text = text.replace(reis, '[world.devices.arm1]\ntype = "fixed_arm"\n'
                              f'wcp = [{", ".join(str(float(v)) for v in wcp)}]\n')
    progs = ('programs = ["droid-watchdog", "droid-servo", "droid-servo-agent", "droid-reis-agent", '
             '"droid-planner"]')
    assert text.count(progs) == 1
    # no planner to end a move on FAULT_FORCE: the F/T sensor guards nothing (droid-ft refuses a
    # guard_arm that runs no droid-planner)
    text, n = re.subn(r'(?m)^guard_arm = "arm1".*\n', "", text)
    assert n <= 1
    return text.replace(progs, 'programs = ["droid-reis-agent"]')


#: How far a fixed holder moves the workpiece back along the seam from start position (i)
#: [mm]: the lead sensor's laser line then lies at s = 95 mm (before the 5 degree turn of
#: step_input at 100 mm), the tool point 100 mm behind it at s = -5 mm (on the lead-in).
SEAM_BACK_MM = 95.0


def fixed_seam_cell(text: str, lateral_mm: float = 0.0, deeper_mm: float = 0.0) -> str:
    """A cell file text with both arms fixed: the Reis at start position (i) of the
    seam-tracking layout, the workpiece on a fixed ``holder`` moved so that the lead
    sensor sees the step_input seam ``lateral_mm`` to its left (+y) and ``deeper_mm``
    deeper (+x), at s = 95 mm (SEAM_BACK_MM); the tool sensor sees the same offsets."""

    from droid.kinematics.transforms import T_to_pose
    from droid.brain.cell.cell_layout import load_layout

    lay = load_layout()
    T_reis, T_hold = lay.start_poses("i")
    S = T_reis @ lay.wrist("standard").T_wcp_sensor  # sensor frame: x depth, y lateral, z travel
    T_hold = T_hold.copy()
    T_hold[:3, 3] += -SEAM_BACK_MM * S[:3, 2] + lateral_mm * S[:3, 1] + deeper_mm * S[:3, 0]
    text = stationary_reis(text, wcp=[float(v) for v in T_to_pose(T_reis)])
    holder = 'holder_robot = "gmf1_karel"'
    assert text.count(holder) == 2  # the camera and the tool sensor (stationary_reis took the touch away)
    text = text.replace(holder, 'holder_robot = "holder"')
    # the guard's workpiece body rides on the Fanuc (docs/guard.md); here a fixed holder carries
    # the workpiece and no arm moves: a cell without the guard
    text = without_table(text, "[guard]")
    hold = ", ".join(repr(float(v)) for v in T_to_pose(T_hold))
    camera = "[world.devices.mvs_camera]"
    assert text.count(camera) == 1  # devices are declared before the sensors that see them
    return text.replace(camera, f'[world.devices.holder]\ntype = "fixed_arm"\nwcp = [{hold}]\n\n{camera}')


_HANDED_OUT: set[int] = set()


def free_port() -> int:
    """A tcp port on 127.0.0.1 free at the time of asking, from below the kernel's ephemeral range
    (net.ipv4.ip_local_port_range, 32768-60999 by default) and never the same twice in a process.
    A port the kernel hands out (bind to port 0) may be handed out again, as the source port of
    the next connect, before the program meant to listen on it has bound it: once, a cell's agent
    found its port taken by a client of the same cell ("Address already in use")."""
    import random
    import socket

    low = 32768
    try:
        low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        pass
    for _ in range(1000):
        port = random.randint(max(1024, low // 2), low - 1)
        if port in _HANDED_OUT:
            continue
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        _HANDED_OUT.add(port)
        return port
    raise RuntimeError(f"no free tcp port below {low} on 127.0.0.1")


def small_tcp_cell(tmp_path: Path, name: str, keys: Path | None = None, extra: str = "") -> Path:
    """A two-host cell over tcp:// on 127.0.0.1: the Brain (names, heartbeat, one remote)
    and host ``a1`` whose arm subunit ``a1`` runs only its agent (no world, no servo).
    With ``keys`` the cell file has a ``[curve]`` table naming that key directory."""
    ports = [free_port() for _ in range(4)]
    text = f'''[cell]
name = "{name}"
run_dir = "{tmp_path}/run"
heartbeat_hz = 60.0

[brain]
host = "brain"
heartbeat = "tcp://127.0.0.1:{ports[0]}"
names = "tcp://127.0.0.1:{ports[1]}"

[world]
enabled = false

[subunits.a1]
class = "arm6r"
robot = "reis_v15"
host = "a1"
agent = "tcp://127.0.0.1:{ports[2]}"
relay = "tcp://127.0.0.1:{ports[3]}"
programs = ["droid-reis-agent"]
'''
    if keys is not None:
        text += f'\n[curve]\nkeys = "{keys}"\n'
    path = tmp_path / f"{name}.toml"
    path.write_text(text + extra)
    return path


def home_at_once(cell, arms, timeout: float = 180) -> None:
    """droid-home every arm in ``arms`` at the same time, as ``droid-home arm1 & droid-home arm2;
    wait`` in a shell script does (thesis §3.4); each must succeed."""
    procs = {arm: subprocess.Popen([sys.executable, "-m", "droid.tasks.home", arm, "--cell", str(cell)], cwd=ROOT,
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for arm in arms}
    try:
        for arm, proc in procs.items():
            _, err = proc.communicate(timeout=timeout)
            assert proc.returncode == 0, f"droid-home {arm}: {err}"
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
