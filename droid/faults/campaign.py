"""A fault campaign: N random (seeded) faults injected into a cell while it moves (issue 8).

Each round: a workload motion starts; after a random delay one fault is
injected for a random time and then cleared (link faults through a
:class:`~droid.faults.proxy.FaultProxy` on the arm's agent link, process
faults by signal, a semaphore holder killed); the campaign waits until the
workload's command has ended, checks that the arm stays where it is while no
command is live, then measures how long until a new command succeeds
(restarting a killed program with ``droid-cell restart``, or the whole cell
when the hardware latched off).  Afterwards every database must be lockable.

Counts (the verdict of the short test; all must be 0):

* **runaway** — (a) a joint moved more than ``QUIET_TOL_COUNTS`` in the
  quiet window while no command was live (after the fault was cleared and
  the workload's command ended, before the next command), or (b) a joint was
  seen outside the commanded envelope (every target of the workload, widened
  by ``ENVELOPE_TOL_COUNTS``, the braking overshoot allowance) while the arm
  was homed;
* **wedged** — databases of the cell whose semaphore could not be taken within
  its timeout after a round;
* **leaked** — shared-memory objects or processes of the cell left after
  ``droid-cell down``;
* **unrecovered** — rounds after which no command succeeded even after a
  full cell restart.

Recovery time per fault: from the fault being cleared to the end of the first
``droid-move`` that succeeds afterwards (including that move's own duration,
:data:`RECOVERY_MOVE_S`).  Timing is reported, never a verdict.

The workload is pluggable (:class:`Workload`): :class:`MoveLoop` alternates
``droid-move`` between joint targets; a seam-tracking workload
(``droid-seamtrack SPEED``) needs only its own ``start``/``envelope``.
"""
from __future__ import annotations

import json
import random
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from droid.brain.runtime import launcher
from droid.brain.cell.cellfile import load_cell
from droid.brain.db.databases import open_local
from droid.brain.db.layouts import FAULT_WATCHDOG
from droid.brain.db.shmdb import cell_objects, pid_alive
from droid.faults import procs
from droid.faults.cells import campaign_cell_text  # noqa: F401  (re-exported)
from droid.cli import RuntimeFailure
from droid.faults.proxy import control

QUIET_S = 1.0  # how long the arm must stay put with no command live
QUIET_TOL_COUNTS = 30  # the position loop's settling after a halt stays within this
ENVELOPE_TOL_COUNTS = 1500  # braking overshoot allowance beyond the commanded envelope
RECOVERY_MOVE_S = 1.5
RECOVERY_TIMEOUT_S = 25.0
SAMPLE_S = 0.02

# Faults: kind -> targets.  Programs whose death or stall latches the amplifiers off
# (the servo, the watchdog, the hardware) need the whole cell restarted (docs/safety.md).
LINK_FAULTS = ("drop", "delay", "duplicate", "cut")
PAUSABLE = ("droid-servo-agent arm1", "droid-planner arm1", "droid-reis-agent arm1", "droid-remote arm1",
            "droid-heartbeat", "droid-names", "droid-servo arm1", "droid-watchdog arm1")
KILLABLE = ("droid-servo-agent arm1", "droid-planner arm1", "droid-reis-agent arm1", "droid-remote arm1",
            "droid-heartbeat", "droid-servo arm1", "droid-watchdog arm1", "droid-sim")


@dataclass(frozen=True)
class Fault:
    kind: str  # drop, delay, duplicate, cut, pause, kill, semkill
    target: str  # a link label, a program name or a database area
    level: float  # probability, or delay [ms]; 0 for the others
    after_s: float  # into the motion
    duration_s: float  # how long the fault lasts before it is cleared

    def describe(self) -> str:
        lvl = f" {self.level:g}" if self.level else ""
        return f"{self.kind}{lvl} {self.target} for {self.duration_s:.2f} s"


#: a cell that declares a collision guard (issue 41): droid-guard paused or killed too -- its
#: record goes stale, every planner ends its move and refuses NORMAL ones (FAULT_GUARD) until it
#: is back (a kill: droid-cell restart droid-guard); the seam-tracking workload's cell has one
GUARD_TARGETS = ("droid-guard",)


def plan(n: int, seed: int, guard: bool = False) -> list[Fault]:
    """N faults, drawn from the seed alone (pure); ``guard``: the cell runs droid-guard, which is
    paused and killed too (the draws of a cell without one are as they were)."""
    pausable, killable = (PAUSABLE + GUARD_TARGETS, KILLABLE + GUARD_TARGETS) if guard else (PAUSABLE, KILLABLE)
    rng = random.Random(seed)
    kinds = ["drop", "delay", "duplicate", "cut", "pause", "kill", "semkill"]
    weights = [2, 2, 1, 2, 3, 3, 1]
    out = []
    for _ in range(n):
        kind = rng.choices(kinds, weights)[0]
        after = round(rng.uniform(0.2, 1.2), 3)
        dur = round(rng.uniform(0.1, 1.5), 3)
        if kind in ("drop", "duplicate"):
            out.append(Fault(kind, "arm1.agent", round(rng.uniform(0.2, 0.9), 2), after, dur))
        elif kind == "delay":
            out.append(Fault(kind, "arm1.agent", round(rng.uniform(10, 300)), after, dur))
        elif kind == "cut":
            out.append(Fault(kind, "arm1", 0.0, after, dur))
        elif kind == "pause":
            out.append(Fault(kind, rng.choice(pausable), 0.0, after, dur))
        elif kind == "kill":
            out.append(Fault(kind, rng.choice(killable), 0.0, after, 0.0))
        else:
            out.append(Fault(kind, rng.choice(["arm1.ctrl_command", "arm1.ctrl_status", "arm1.command",
                                               "arm1.status"]), 0.0, after, 0.0))
    return out


def droid(module: str, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, timeout=timeout)


class Workload:
    """What the cell does while faults happen.  ``start`` returns a running Popen (the live
    command); ``envelope`` the joint bounds [counts] (2 x 6) the motion may reach."""

    name = "workload"

    def start(self, cell_path: Path, round_no: int) -> subprocess.Popen:
        raise NotImplementedError

    def envelope(self) -> np.ndarray:
        raise NotImplementedError

    def recovery_target(self) -> np.ndarray:
        """Joint target [counts] of the ``droid-move`` that proves the cell recovered."""
        raise NotImplementedError


class MoveLoop(Workload):
    """``droid-move arm1 joint`` back and forth between two targets [counts]."""

    name = "droid-move loop"

    def __init__(self, a=(0, 0, 0, 0, 0, 0), b=(20000, -10000, 10000, 30000, 20000, 40000), seconds: float = 2.5):
        self.targets = [np.asarray(a, int), np.asarray(b, int)]
        self.seconds = seconds

    def start(self, cell_path, round_no):
        t = self.targets[round_no % 2]
        return subprocess.Popen([sys.executable, "-m", "droid.tasks.move", "arm1", "joint", *map(str, t),
                                 str(self.seconds), "--cell", str(cell_path)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    def recovery_target(self) -> np.ndarray:
        return self.targets[0]

    def target(self, round_no: int) -> np.ndarray:
        return self.targets[round_no % 2]

    def envelope(self):
        t = np.stack(self.targets)
        return np.stack([t.min(axis=0), t.max(axis=0)])


class CommandWorkload(Workload):
    """Any task program as the workload: ``argv(cell_path, round_no)`` gives its module and
    arguments (run as ``python -m``).  A seam-tracking workload is one entry::

        WORKLOADS["seamtrack"] = lambda: CommandWorkload(
            "droid-seamtrack 16", lambda cell, i: ["droid.tasks.seamtrack", "16", "--cell", str(cell)],
            envelope=SEAM_ENVELOPE_COUNTS, recovery_target=SEAM_START_COUNTS)
    """

    def __init__(self, name: str, argv, envelope, recovery_target):
        self.name, self._argv = name, argv
        self._envelope = np.asarray(envelope, int)
        self._recovery = np.asarray(recovery_target, int)

    def start(self, cell_path, round_no):
        return subprocess.Popen([sys.executable, "-m", *self._argv(cell_path, round_no)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    def envelope(self):
        return self._envelope

    def recovery_target(self):
        return self._recovery


class SeamTrackLoop(Workload):
    """``droid-seamtrack SPEED --start i --length MM`` over and over: every round moves the
    GMF1 to its holding pose and the Reis to the seam start of layout position (i), then
    tracks.  Needs the seam-tracking cell (droid.faults.cells.seam_campaign_cell_text) and
    both arms homed.  The envelope: the joint box from home to the start and along the
    first ``length_mm`` of the seam, ``ENVELOPE_TOL_COUNTS`` wider (the tracker's own
    corrections stay within a few mm of the seam)."""

    name = "droid-seamtrack loop"
    needs_holder = True
    recovery_move_s = 5.0  # back to the seam start from anywhere on it, or from home

    def __init__(self, speed_mm_s: float = 16.0, length_mm: float = 120.0, position: str = "i"):
        from droid.kinematics import load_robot
        from droid.brain.cell.cell_layout import load_layout

        self.speed_mm_s, self.length_mm, self.position = speed_mm_s, length_mm, position
        lay = load_layout()
        tool = load_robot(lay.robots[lay.tool_robot]).with_base(lay.base(lay.tool_robot))
        T_start, _ = lay.start_poses(position)
        T_tool_start = T_start @ lay.wrist().T_wcp_tool
        q = tool.ik(T_start, np.zeros(6))
        qs = [np.zeros(6), q]
        for d in np.linspace(0.0, length_mm + 20.0, 8):  # along the seam's start heading (tool z)
            for lateral in (-10.0, 10.0):
                T = T_tool_start.copy()
                T[:3, 3] += d * T_tool_start[:3, 2] + lateral * T_tool_start[:3, 1]
                q = tool.ik(T @ np.linalg.inv(lay.wrist().T_wcp_tool), q)
                qs.append(q)
        counts = np.array([tool.gearing.joints_to_counts(v) for v in qs])
        self._start = np.rint(counts[1]).astype(int)
        self._envelope = np.stack([np.floor(counts.min(axis=0)), np.ceil(counts.max(axis=0))]).astype(int)

    def start(self, cell_path, round_no):
        return subprocess.Popen([sys.executable, "-m", "droid.tasks.seamtrack", f"{self.speed_mm_s:g}",
                                 "--start", self.position, "--length", f"{self.length_mm:g}", "--quiet",
                                 "--cell", str(cell_path)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    def envelope(self):
        return self._envelope

    def recovery_target(self):
        return self._start


WORKLOADS = {"move": MoveLoop, "seamtrack": SeamTrackLoop}


@dataclass
class Round:
    fault: dict
    recovery_s: float | None = None
    restarted: str = ""  # "", "program", "cell"
    runaway: list = field(default_factory=list)
    wedged: list = field(default_factory=list)
    move_rc: int | None = None
    move_error: str = ""  # the workload command's last words when it failed
    idle_check_s: float = 0.0  # fault cleared -> command ended, arm idle and checked (not in recovery_s)
    recovery_failures: list = field(default_factory=list)  # stderr of recovery moves that failed
    false_success: bool = False  # the workload's command exited 0 but the arm is not at its target
    orphan_move_counts: list | None = None  # the task failed, yet its command went on moving the arm


class Watcher:
    """Samples the arm's own Status (host arm1's database) every SAMPLE_S in a thread and
    notes any homed position outside the envelope."""

    def __init__(self, cell, envelope: np.ndarray):
        self.cell, self.lo, self.hi = cell, envelope[0] - ENVELOPE_TOL_COUNTS, envelope[1] + ENVELOPE_TOL_COUNTS
        self.outside: list = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self.enabled = threading.Event()
        self._t.start()

    def _run(self):
        db = None
        while not self._stop.is_set():
            time.sleep(SAMPLE_S)
            if not self.enabled.is_set():
                if db is not None:
                    db.close()
                    db = None
                continue
            try:
                if db is None:
                    db = open_local(self.cell, self.cell.subunit("arm1"), "ctrl_status", timeout_s=0.5)
                rec = db.read()
            except Exception:
                continue
            if int(rec["homed"]):
                pos = np.asarray(rec["encoder_pos"], int)
                if np.any(pos < self.lo) or np.any(pos > self.hi):
                    self.outside.append(pos.tolist())
        if db is not None:
            db.close()

    def include(self, pos) -> None:
        """Widen the envelope to a position the arm was legitimately brought to (homing)."""
        pos = np.asarray(pos, int)
        self.lo = np.minimum(self.lo, pos - ENVELOPE_TOL_COUNTS)
        self.hi = np.maximum(self.hi, pos + ENVELOPE_TOL_COUNTS)

    def stop(self):
        self._stop.set()
        self._t.join(2)


def arm_status(cell) -> tuple[np.ndarray, int, int]:
    """(encoder_pos [counts], fault bits, homed) from the arm's own Status record."""
    pos, fault, homed, _ = arm_status4(cell)
    return pos, fault, homed


def arm_status4(cell):
    db = open_local(cell, cell.subunit("arm1"), "ctrl_status")
    try:
        rec = db.read()
        return (np.asarray(rec["encoder_pos"], int).copy(), int(rec["fault"]), int(rec["homed"]),
                int(rec["busy"]))
    finally:
        db.close()


def wait_idle(cell, timeout_s: float = 20.0) -> bool:
    """Until the arm's planner is not busy (no command of its own in progress)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if not arm_status4(cell)[3]:
                return True
        except Exception:
            return False
        time.sleep(0.05)
    return False


class Campaign:
    def __init__(self, cell_path: Path, workload: Workload, seed: int, log=print):
        self.path = cell_path
        self.cell = load_cell(cell_path)
        self.workload = workload
        self.seed = seed
        self.log = log
        self.proxy: subprocess.Popen | None = None  # droid-fault proxy arm1.agent
        self.full_restarts = 0
        self.notes: list[str] = []  # why recovery moves failed, this round

    # -- the cell ----------------------------------------------------------------
    def up(self) -> None:
        self.cell.run_dir.mkdir(parents=True, exist_ok=True)
        if self.proxy is None:  # (droid-cell down removes its socket file: a new one each time)
            self.proxy = subprocess.Popen([sys.executable, "-m", "droid.faults.cli", "--cell", str(self.path),
                                           "proxy", "arm1.agent", "--seed", str(self.seed + self.full_restarts)],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            deadline = time.monotonic() + 20
            while True:
                try:
                    control(self.cell, "arm1.agent", {"get": True}, timeout_s=0.5)
                    break
                except RuntimeFailure:
                    if time.monotonic() > deadline or self.proxy.poll() is not None:
                        raise RuntimeError("the fault proxy did not start") from None
        out = droid("droid.brain.runtime.launcher", "up", "--cell", str(self.path))
        if out.returncode != 0:
            raise RuntimeError(f"droid-cell up failed: {out.stderr.strip()}")
        for arm in ("arm1", "gmf1") if getattr(self.workload, "needs_holder", False) else ("arm1",):
            out = droid("droid.tasks.home", arm, "--cell", str(self.path), timeout=200)
            if out.returncode != 0:
                raise RuntimeError(f"droid-home {arm} failed: {out.stderr.strip()}")

    def down(self) -> list[str]:
        """Bring the cell down; returns what leaked (shm objects, live processes)."""
        state = launcher.read_state(self.cell) or {"programs": []}
        pids = [p["pid"] for p in state["programs"]]
        out = droid("droid.brain.runtime.launcher", "down", "--cell", str(self.path))
        if self.proxy is not None:
            self.proxy.terminate()
            try:
                self.proxy.wait(10)
            except subprocess.TimeoutExpired:
                self.proxy.kill()
                self.proxy.wait()
            self.proxy = None
        leaked = list(cell_objects(self.cell.name)) + [f"pid {p}" for p in pids if pid_alive(p)]
        if out.returncode != 0:
            leaked.append(f"droid-cell down: {out.stderr.strip()}")
        return leaked

    def close(self) -> list[str]:
        return self.down()

    # -- one fault ---------------------------------------------------------------
    def inject(self, f: Fault) -> callable:
        """Start fault ``f``; returns the function that clears it."""
        if f.kind in LINK_FAULTS:
            key = {"drop": "drop", "duplicate": "duplicate", "delay": "delay_ms", "cut": "cut"}[f.kind]
            self._link({key: (True if f.kind == "cut" else f.level)})
            return lambda: self._link({"drop": 0.0, "duplicate": 0.0, "delay_ms": 0.0, "jitter_ms": 0.0,
                                       "cut": False})
        if f.kind == "pause":
            procs.signal_program(self.cell, f.target, "pause")
            return lambda: procs.signal_program(self.cell, f.target, "resume")
        if f.kind == "kill":
            procs.signal_program(self.cell, f.target, "kill")
            return lambda: None
        if f.kind == "semkill":
            self._kill_holder()
            return lambda: None
        raise ValueError(f.kind)

    def _link(self, faults: dict) -> None:
        ans = control(self.cell, "arm1.agent", {"set": faults})
        if not ans.get("ok"):
            raise RuntimeError(f"fault proxy refused {faults}: {ans}")

    def prepare(self, f: Fault) -> None:
        """Start what a fault needs ahead of time, so that it lands when planned: the
        semaphore holder (a Python process takes ~0.2-2 s to start on a loaded machine)."""
        self._holder = None
        if f.kind == "semkill":
            sub, area = f.target.split(".")
            code = ("import sys,time\n"
                    "from droid.brain.cell.cellfile import load_cell\n"
                    "from droid.brain.db.databases import open_brain, open_local\n"
                    "c = load_cell(sys.argv[1]); s = c.subunit(sys.argv[2]); a = sys.argv[3]\n"
                    "db = (open_local if a.startswith('ctrl_') else open_brain)(c, s, a)\n"
                    "print('ready', flush=True); sys.stdin.readline()\n"
                    "db._acquire(); print('held', flush=True); time.sleep(60)\n")
            self._holder = subprocess.Popen([sys.executable, "-c", code, str(self.path), sub, area],
                                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            self._holder.stdout.readline()

    def _kill_holder(self) -> None:
        """The prepared process takes the database's semaphore (recording itself as the
        holder, as every program does) and is SIGKILLed holding it."""
        p = self._holder
        try:
            p.stdin.write("go\n")
            p.stdin.flush()
            p.stdout.readline()
        finally:
            p.kill()
            p.wait()
            p.stdout.close()
            p.stdin.close()
            self._holder = None

    def recover(self, f: Fault, cleared_at: float) -> tuple[float | None, str]:
        """Until a new command succeeds: restart a dead program, or the whole cell."""
        restarted = ""
        rows = procs.programs(self.cell)
        dead = [r["name"] for r in rows if not r["alive"]]
        _, fault, _ = arm_status(self.cell)
        if any(d in ("droid-servo arm1", "droid-watchdog arm1", "droid-sim") for d in dead) \
                or fault & FAULT_WATCHDOG:
            return self._full_restart(cleared_at)
        for name in dead:
            out = droid("droid.brain.runtime.launcher", "restart", name, "--cell", str(self.path))
            if out.returncode != 0:
                return self._full_restart(cleared_at)
            restarted = "program"
        deadline = time.monotonic() + RECOVERY_TIMEOUT_S
        while time.monotonic() < deadline:
            if self._move_ok():
                return time.monotonic() - cleared_at, restarted
            time.sleep(0.2)
        return self._full_restart(cleared_at)

    def _move_ok(self) -> bool:
        pos, _, homed = arm_status(self.cell)
        if not homed:
            return False
        t = self.workload.recovery_target()
        seconds = getattr(self.workload, "recovery_move_s", RECOVERY_MOVE_S)
        out = droid("droid.tasks.move", "arm1", "joint", *map(str, t), str(seconds), "--cell", str(self.path),
                    timeout=60)
        if out.returncode != 0:
            self.notes.append(out.stderr.strip()[-200:])
        return out.returncode == 0

    def _full_restart(self, cleared_at: float) -> tuple[float | None, str]:
        self.full_restarts += 1
        leaked = self.down()
        if leaked:
            self.leaked_on_restart.extend(leaked)
        for attempt in (1, 2):
            try:
                self.up()
                break
            except RuntimeError as exc:
                self.log(f"  full restart failed (attempt {attempt}): {exc}")
                self.leaked_on_restart.extend(self.down())
        else:
            return None, "cell"
        self.watcher.include(arm_status(self.cell)[0])
        return (time.monotonic() - cleared_at, "cell") if self._move_ok() else (None, "cell")

    # -- the campaign ------------------------------------------------------------
    def run(self, faults: list[Fault]) -> dict:
        self.leaked_on_restart: list = []
        rounds: list[Round] = []
        watcher = Watcher(self.cell, self.workload.envelope())
        rng = random.Random(self.seed + 7)
        self.watcher = watcher
        try:
            self.up()
            watcher.include(arm_status(self.cell)[0])
            for i, f in enumerate(faults):
                r = Round(asdict(f))
                watcher.enabled.set()
                self.prepare(f)
                move = self.workload.start(self.path, i)
                time.sleep(f.after_s)
                try:
                    clear = self.inject(f)
                except Exception as exc:  # the target was already gone: count as a no-op round
                    self.log(f"  could not inject {f.describe()}: {exc}")
                    clear = lambda: None  # noqa: E731
                time.sleep(f.duration_s)
                try:
                    clear()
                except Exception as exc:
                    self.log(f"  could not clear {f.describe()}: {exc}")
                cleared_at = time.monotonic()
                try:
                    r.move_rc = move.wait(timeout=60)
                except subprocess.TimeoutExpired:
                    move.kill()
                    r.move_rc = move.wait()
                if move.stderr is not None:
                    err = move.stderr.read().strip()
                    move.stderr.close()
                    if r.move_rc:
                        r.move_error = err[-200:]
                # the task has ended; a command it left in the cell (a failed task) may still
                # be carried out: that is an orphan move, recorded, not a runaway
                try:
                    at_exit = arm_status(self.cell)[0]
                    if all(x["alive"] for x in procs.programs(self.cell)) and wait_idle(self.cell):
                        time.sleep(0.4)  # the halt and the position loop settle
                        a, fault, homed_a = arm_status(self.cell)
                        if r.move_rc != 0 and np.any(np.abs(a - at_exit) > QUIET_TOL_COUNTS):
                            r.orphan_move_counts = (a - at_exit).tolist()
                        target = getattr(self.workload, "target", lambda _i: None)(i)
                        if r.move_rc == 0 and target is not None and np.any(np.abs(a - target) > 50):
                            r.false_success = True
                        # no command is live now: the arm must stay where it is
                        time.sleep(QUIET_S)
                        b, _, homed_b = arm_status(self.cell)
                        if homed_a and homed_b and np.any(np.abs(b - a) > QUIET_TOL_COUNTS):
                            r.runaway.append({"moved_while_idle_counts": (b - a).tolist()})
                except Exception as exc:  # a database gone with a killed program: no idle check
                    self.log(f"  idle check skipped: {exc}")
                ready_at = time.monotonic()
                watcher.enabled.clear()  # homing after a restart leaves the envelope
                r.idle_check_s = round(ready_at - cleared_at, 2)
                self.notes = []
                r.recovery_s, r.restarted = self.recover(f, ready_at)
                r.recovery_failures = sorted(set(self.notes))[:5]
                if watcher.outside:
                    r.runaway.append({"outside_envelope": watcher.outside[:3]})
                    watcher.outside.clear()
                r.wedged = procs.wedged_databases(self.cell)
                rounds.append(r)
                rec = "FAILED" if r.recovery_s is None else f"{r.recovery_s:.2f} s"
                self.log(f"[{i + 1}/{len(faults)}] {f.describe()}: move rc {r.move_rc}, recovered {rec}"
                         f"{' (' + r.restarted + ' restarted)' if r.restarted else ''}"
                         f"{' RUNAWAY ' + json.dumps(r.runaway) if r.runaway else ''}"
                         f"{' WEDGED ' + ','.join(r.wedged) if r.wedged else ''}"
                         f"{' FALSE-SUCCESS' if r.false_success else ''}"
                         f"{' ORPHAN-MOVE ' + str(r.orphan_move_counts) if r.orphan_move_counts else ''}")
                time.sleep(rng.uniform(0.0, 0.3))
        finally:
            watcher.stop()
            leaked = self.close()
        return summarize(rounds, leaked + self.leaked_on_restart, self.full_restarts)


def summarize(rounds: list[Round], leaked: list, full_restarts: int) -> dict:
    rec = [r.recovery_s for r in rounds if r.recovery_s is not None]
    by_kind: dict[str, list] = {}
    for r in rounds:
        if r.recovery_s is not None:
            by_kind.setdefault(r.fault["kind"], []).append(r.recovery_s)
    pct = (lambda xs, q: float(np.percentile(xs, q)) if xs else None)
    return {
        "faults": len(rounds),
        "runaway": sum(1 for r in rounds if r.runaway),
        "wedged": sum(len(r.wedged) for r in rounds),
        "leaked": len(leaked),
        "leaked_items": leaked,
        "unrecovered": sum(1 for r in rounds if r.recovery_s is None),
        "false_success": sum(1 for r in rounds if r.false_success),
        "orphan_moves": sum(1 for r in rounds if r.orphan_move_counts),
        "full_restarts": full_restarts,
        "program_restarts": sum(1 for r in rounds if r.restarted == "program"),
        "recovery_s": {"median": pct(rec, 50), "p90": pct(rec, 90), "max": max(rec) if rec else None},
        "recovery_s_by_kind": {k: {"n": len(v), "median": round(float(np.median(v)), 2),
                                   "max": round(max(v), 2)} for k, v in sorted(by_kind.items())},
        "rounds": [asdict(r) for r in rounds],
    }
