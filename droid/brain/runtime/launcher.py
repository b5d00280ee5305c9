"""droid-cell: bring a cell up, report on it, bring it down (thesis §3.2 "initialization software").

``droid-cell up [--cell FILE] [--host H]...``
    creates the cell's databases, then starts the name space, then in
    parallel the heartbeat, one ``droid-remote`` per subunit, every
    subunit's programs and the ``droid-sim`` world; waits for each program's
    readiness handshake (``--ready-fd``) and returns.  If any program fails
    to come up, everything started is stopped and removed again.
``droid-cell up --replay FILE``
    a *replay* cell: only the Brain's databases (no name space, heartbeat,
    remotes, world or subunit programs), for ``droid-replay FILE`` to play a
    recording into (docs/observe.md); ``down`` removes it as any cell.
``droid-cell init``
    only creates the databases, for a cell started by hand (scripts/start-cell.sh).
``droid-cell status [--json]``
    every program with its pid, state, liveness and last tick.
``droid-cell restart NAME``
    starts one program of the cell again (after it died or was killed: a
    fault, docs/safety.md), waits for its handshake and records its new pid,
    so ``down`` stops it.  NAME as ``status`` shows it (``droid-servo arm1``)
    or its key.
``droid-cell down``
    stops every program (SIGTERM, then SIGKILL after a grace period) and
    removes every shared-memory object and semaphore of the cell.

Exit codes: 0 ok; 2 bad cell file or arguments; 1 runtime failure (already up,
not up, a program failed to start).  Programs run in their own sessions and
log to ``<run_dir>/logs/<key>.log``; the launcher records them in
``<run_dir>/cell.json``.
"""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field

from droid.brain.cell.cellfile import REMOTES_ONE, Cell, load_cell
from droid.brain.db.databases import create_databases
from droid.brain.db.layouts import LATENESS_NO_RECORD, PROC_STATE_NAMES, PROC_STATUS_LAYOUT
from droid.brain.runtime.program import presence_key, shared_key, use_cell
from droid.brain.runtime.rt import normal_scheduler
from droid.brain.runtime.sensor_link import LINK_AGENT, link_kind
from droid.brain.db.shmdb import (Database, NoDatabase, cell_objects, db_name, pid_alive,
                               remove_cell_objects, unlink_database)
from droid.cli import ArgumentParser, BadInput, RuntimeFailure, run, timeout_s
from droid.brain.cell.registry import program, programs, twin, validate_cell

PROG = "droid-cell"
READY_TIMEOUT_S = 30.0
STOP_GRACE_S = 5.0
LIVE_AGE_S = 2.0  # a presence record older than this counts as stalled


@dataclass
class Spec:
    """One program of the cell."""

    key: str
    prog: str
    args: list[str]
    host: str
    pid: int = 0
    argv: list[str] = field(default_factory=list)


def cell_programs(cell: Cell, hosts: set[str] | None = None) -> tuple[list[Spec], list[Spec]]:
    """(first, rest): the programs of start group 0 (the name space; the world: the hardware is
    powered before the programs that drive it, §4.1.4), then group 1 in parallel after them.
    Each program's group is its declaration's ``start`` (droid.brain.cell.registry)."""
    want = (lambda h: True) if hosts is None else (lambda h: h in hosts)
    specs = []
    if want(cell.brain_host):
        specs.append(Spec(presence_key("droid-names"), "droid-names", [], cell.brain_host))
        specs.append(Spec(presence_key("droid-heartbeat"), "droid-heartbeat", [], cell.brain_host))
        specs.extend(remote_specs(cell))
        from droid.guard.gate import guard_runs  # beside the Brain, imported where used (as check_guard_homes)

        if guard_runs(cell):  # the live collision guard (issue 41; docs/guard.md)
            specs.append(Spec(presence_key("droid-guard"), "droid-guard", [], cell.brain_host))
    if cell.world.get("enabled", True) and want(cell.world.get("host", cell.brain_host)):
        specs.append(Spec(presence_key("droid-sim"), "droid-sim", [], cell.world["host"]))
    shared: dict[tuple[str, str], Spec] = {}  # [cell] share: (program, host) -> its one process
    for sub in cell.subunits.values():
        if want(sub.host):
            for prog in sub.programs:
                if prog not in cell.share:
                    specs.append(Spec(presence_key(prog, sub.name), prog, [sub.name], sub.host))
                    continue
                spec = shared.get((prog, sub.host))
                if spec is None:  # the host's one process, where its first subunit puts it
                    spec = shared[prog, sub.host] = Spec("", prog, [], sub.host)
                    specs.append(spec)
                spec.args.append(sub.name)
    for spec in shared.values():  # one subunit: its own key, as if not shared
        spec.key = shared_key(spec.prog, [cell.subunit(n) for n in spec.args])
    first = [s for s in specs if program(s.prog).start == 0]
    rest = [s for s in specs if program(s.prog).start != 0]
    return first, rest


def remote_specs(cell: Cell) -> list[Spec]:
    """The Brain's remotes (thesis §3.2): one ``droid-remote NAME`` a subunit; with ``[brain]
    remotes = "one"`` one ``droid-remote NAME...`` for every agent-linked subunit (presence
    ``remote``), and each serial-linked sensor still its own."""
    subs = list(cell.subunits.values())
    shared = [s.name for s in subs if link_kind(cell, s) == LINK_AGENT] if cell.remotes == REMOTES_ONE else []
    specs = [Spec(presence_key("droid-remote", s.name), "droid-remote", [s.name], cell.brain_host)
             for s in subs if s.name not in shared]
    if shared:
        specs.insert(0, Spec(presence_key("droid-remote"), "droid-remote", shared, cell.brain_host))
    return specs


#: Share of this host's CPUs a cell may ask for before droid-cell up warns: above it the
#: heartbeat's exchanges start to miss (docs/benchmarks.md "Scale", bench/bench_scale.py).
HOST_CPU_BUDGET = 0.7
#: The real-time budget: the share of one core per CPU [%] that the SCHED_FIFO programs of a
#: cell may declare before droid-cell up refuses it (without --force).  The kernel stops every
#: SCHED_FIFO task of a CPU for the rest of the second once they used sched_rt_runtime_us of
#: it (950 ms: "RT throttling", ~50 ms of silence that makes the servo brake); half a core
#: leaves the margin for a slower host of the same kind and for bursts (docs/architecture.md
#: "Real time", docs/benchmarks.md "Real-time budget").
RT_BUDGET_PCT_PER_CPU = 50.0


@dataclass
class Demand:
    """What the programs ``droid-cell up`` starts here ask of this host (issue 28 item 4,
    issue 40 item 1): the sums of their declared ``cpu_pct`` (droid-sim with its twins') and
    ``rss_mb``, and the part of it at SCHED_FIFO (``fifo``: program -> share of one core)."""

    programs: int
    cpu_pct: float  # share of one core [%]
    rss_mb: float
    cpus: int  # CPUs this process may run on
    mem_available_mb: float | None
    fifo: dict[str, float] = field(default_factory=dict)  # SCHED_FIFO program -> share [%] (summed per name)

    @property
    def fifo_pct(self) -> float:
        """The SCHED_FIFO programs' declared share of one core [%], all of them."""
        return sum(self.fifo.values())

    @property
    def fifo_pct_per_cpu(self) -> float:
        """:attr:`fifo_pct` spread over this host's CPUs [% of one core per CPU]."""
        return self.fifo_pct / max(self.cpus, 1)

    def over_rt_budget(self) -> str | None:
        """One line naming the largest real-time programs when the SCHED_FIFO share per CPU is
        over :data:`RT_BUDGET_PCT_PER_CPU`; None within it."""
        if self.fifo_pct_per_cpu <= RT_BUDGET_PCT_PER_CPU:
            return None
        top = sorted(self.fifo.items(), key=lambda kv: -kv[1])
        named = ", ".join(f"{n} {v:.0f} %" for n, v in top[:4]) + (", ..." if len(top) > 4 else "")
        cpus = f"{self.cpus} CPU{'s' if self.cpus != 1 else ''}"
        return (f"its SCHED_FIFO programs declare {self.fifo_pct:.0f} % of one core on {cpus}: "
                f"{self.fifo_pct_per_cpu:.0f} % a CPU, over the real-time budget of "
                f"{RT_BUDGET_PCT_PER_CPU:.0f} % a CPU ({named})")

    def warnings(self) -> list[str]:
        out = []
        budget = HOST_CPU_BUDGET * 100.0 * self.cpus
        if self.cpu_pct > budget:
            out.append(f"its {self.programs} programs need about {self.cpu_pct:.0f} % of one core "
                       f"(their declared costs), over {HOST_CPU_BUDGET:.0%} of this host's {self.cpus} "
                       f"CPU{'s' if self.cpus != 1 else ''}: expect missed heartbeat exchanges and programs "
                       f"LAGGING in droid-cell status; split the cell over hosts (docs/benchmarks.md \"Scale\")")
        if self.mem_available_mb is not None and self.rss_mb > self.mem_available_mb:
            out.append(f"its {self.programs} programs need about {self.rss_mb:.0f} MB resident and this "
                       f"host has {self.mem_available_mb:.0f} MB available")
        return out


def _mem_available_mb() -> float | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def demand(cell: Cell, specs: list[Spec]) -> Demand:
    """The host's share of ``specs``: each program's declared cost, droid-sim's with the
    twins of ``[world.devices]`` (droid.brain.cell.registry.Program.cpu_pct, Twin.cpu_pct); the
    SCHED_FIFO part where the cell asks for it (``[cell] sched_fifo``)."""
    cpu = rss = 0.0
    fifo: dict[str, float] = {}
    for s in specs:
        p = program(s.prog)
        share = p.cpu_pct
        rss += p.rss_mb
        if len(s.args) > 1:  # a process serving several subunits: each further one's share
            share += p.cpu_pct_each * (len(s.args) - 1)
        if s.prog == "droid-sim":
            for opts in cell.world.get("devices", {}).values():
                try:
                    share += twin(opts["type"]).cpu_pct
                except (KeyError, TypeError):
                    pass  # validate_cell names an unknown twin before this runs
        cpu += share
        if cell.sched_fifo and p.sched == "fifo":
            fifo[s.prog] = fifo.get(s.prog, 0.0) + share
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    return Demand(len(specs), cpu, rss, cpus, _mem_available_mb(), fifo)


def state_path(cell: Cell, hosts: set[str] | None = None) -> str:
    """``cell.json`` for a whole cell, ``cell@h1,h2.json`` for the programs of some hosts."""
    suffix = "" if not hosts else "@" + ",".join(sorted(hosts))
    return str(cell.run_dir / f"cell{suffix}.json")


def read_state(cell: Cell) -> dict | None:
    """The merged records of every ``droid-cell up`` of this cell (None if there is none)."""
    if not cell.run_dir.is_dir():
        return None
    files = sorted(f for f in os.listdir(cell.run_dir) if f.startswith("cell") and f.endswith(".json"))
    if not files:
        return None
    merged: dict = {"programs": []}
    for name in files:
        try:
            with open(cell.run_dir / name) as f:
                merged["programs"].extend(json.load(f).get("programs", []))
        except (OSError, ValueError):
            continue
    return merged


def _start(cell: Cell, specs: list[Spec], log_dir: str) -> dict[int, tuple[Spec, subprocess.Popen]]:
    started = {}
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    for spec in specs:
        r, w = os.pipe()
        spec.argv = [sys.executable, "-m", programs()[spec.prog], "--cell", str(cell.path),
                     *spec.args, "--ready-fd", str(w)]
        with open(os.path.join(log_dir, f"{spec.key}.log"), "ab") as log:
            proc = subprocess.Popen(spec.argv, pass_fds=(w,), stdin=subprocess.DEVNULL,
                                    stdout=log, stderr=subprocess.STDOUT,
                                    start_new_session=True, env=env, preexec_fn=normal_scheduler)
        os.close(w)
        spec.pid = proc.pid
        started[r] = (spec, proc)
    return started


def _await_ready(started: dict, timeout_s: float, log_dir: str) -> None:
    pending = dict(started)
    deadline = time.monotonic() + timeout_s
    try:
        while pending:
            left = deadline - time.monotonic()
            if left <= 0:
                names = ", ".join(s.key for s, _ in pending.values())
                raise RuntimeFailure(f"not ready within {timeout_s:g} s: {names}")
            ready, _, _ = select.select(list(pending), [], [], min(left, 0.5))
            for fd in ready:
                data = os.read(fd, 16)
                spec, proc = pending.pop(fd)
                os.close(fd)
                if not data:
                    code = proc.wait(timeout=2) if proc.poll() is None else proc.returncode
                    fail = BadInput if code == 2 else RuntimeFailure  # a program refusing its input: exit 2
                    raise fail(f"{spec.prog} {' '.join(spec.args)} exited (code {code}) "
                               f"before it was ready: {_last_line(log_dir, spec.key)}")
    finally:
        for fd in pending:
            os.close(fd)


def _last_line(log_dir: str, key: str) -> str:
    try:
        with open(os.path.join(log_dir, f"{key}.log"), "rb") as f:
            lines = [ln for ln in f.read().decode(errors="replace").splitlines() if ln.strip()]
        return lines[-1] if lines else "(no output)"
    except OSError:
        return "(no log)"


def _write_state(cell: Cell, specs: list[Spec], hosts) -> None:
    state = {"cell": cell.name, "cell_file": str(cell.path), "hosts": sorted(hosts) if hosts else None,
             "started_at": time.time(), "launcher_pid": os.getpid(),
             "programs": [asdict(s) for s in specs]}
    path = state_path(cell, hosts)
    with open(path + ".tmp", "w") as f:
        json.dump(state, f, indent=1)
    os.replace(path + ".tmp", path)


def up(cell: Cell, hosts: set[str] | None, timeout_s: float, force: bool = False) -> list[Spec]:
    """Start the programs of ``hosts`` (None: all) and wait until each is ready.  A cell whose
    SCHED_FIFO programs declare more than the real-time budget of this host is refused
    (BadInput) before anything is made, unless ``force``."""
    first, rest = cell_programs(cell, hosts)
    need = demand(cell, first + rest)
    over = need.over_rt_budget()
    if over and not force:
        raise BadInput(f"cell {cell.name}: {over}; not started (droid-cell up --force starts it anyway)")
    state = read_state(cell)
    if state is not None:
        running = [p for p in state.get("programs", []) if pid_alive(p.get("pid", 0))]
        mine = [p for p in running if hosts is None or p.get("host") in hosts]
        if mine:
            raise RuntimeFailure(f"cell {cell.name!r} is already up ({len(mine)} programs running); "
                                 f"run 'droid-cell down' first")
        if not running:
            _cleanup(cell)  # leftovers of a crashed cell
    log_dir = str(cell.run_dir / "logs")
    os.makedirs(log_dir, exist_ok=True)
    dbs = create_databases(cell, hosts)
    for db in dbs:
        db.close()
    if over:
        print(f"{PROG}: warning: cell {cell.name}: {over} (--force)", file=sys.stderr, flush=True)
    for line in need.warnings():  # before any program starts
        print(f"{PROG}: warning: cell {cell.name}: {line}", file=sys.stderr, flush=True)
    specs: list[Spec] = []
    try:
        for group in (first, rest):
            started = _start(cell, group, log_dir)
            specs.extend(s for s, _ in started.values())
            _write_state(cell, specs, hosts)
            _await_ready(started, timeout_s, log_dir)
    except BaseException:
        _stop_pids([s.pid for s in specs], STOP_GRACE_S)
        if hosts is None:
            _cleanup(cell)
        else:  # other hosts of this cell may be running here: remove only what we made
            for db in dbs:
                unlink_database(db.name)
            for spec in specs:
                unlink_database(db_name(cell.name, "proc", spec.key))
            try:
                os.unlink(state_path(cell, hosts))
            except OSError:
                pass
        raise
    return specs


def up_replay(cell: Cell, recording: str) -> None:
    """A replay cell: the Brain's databases only, and a state file naming the recording."""
    if not os.path.isfile(recording):
        raise BadInput(f"--replay {recording}: no such file")
    state = read_state(cell)
    if state is not None:
        if any(pid_alive(p.get("pid", 0)) for p in state.get("programs", [])):
            raise RuntimeFailure(f"cell {cell.name!r} is already up; run 'droid-cell down' first")
        _cleanup(cell)
    os.makedirs(cell.run_dir / "logs", exist_ok=True)
    for db in create_databases(cell, {cell.brain_host}, brain_only=True):
        db.close()
    state = {"cell": cell.name, "cell_file": str(cell.path), "hosts": [cell.brain_host], "started_at": time.time(),
             "launcher_pid": os.getpid(), "replay": os.path.abspath(recording), "programs": []}
    path = state_path(cell)
    with open(path + ".tmp", "w") as f:
        json.dump(state, f, indent=1)
    os.replace(path + ".tmp", path)


def _stop_pids(pids: list[int], grace_s: float) -> list[int]:
    """SIGTERM every process group, wait, SIGKILL survivors; returns those killed hard."""
    for pid in pids:
        _signal(pid, signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    while time.monotonic() < deadline and any(pid_alive(p) for p in pids):
        _reap()
        time.sleep(0.02)
    hard = [p for p in pids if pid_alive(p)]
    for pid in hard:
        _signal(pid, signal.SIGKILL)
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and any(pid_alive(p) for p in hard):
        _reap()
        time.sleep(0.02)
    _reap()
    return hard


def _signal(pid: int, sig: int) -> None:
    if pid <= 0:
        return
    try:
        os.killpg(pid, sig)  # programs lead their own session/group
    except (ProcessLookupError, PermissionError):
        try:
            os.kill(pid, sig)
        except (ProcessLookupError, PermissionError):
            pass


def _reap() -> None:
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return


def _cleanup(cell: Cell) -> list[str]:
    removed = remove_cell_objects(cell.name)
    for name in os.listdir(cell.run_dir) if cell.run_dir.is_dir() else []:
        path = cell.run_dir / name
        if name != "logs" and not path.is_dir():  # sockets, cell*.json
            try:
                path.unlink()
            except OSError:
                pass
    return removed


def down(cell: Cell, grace_s: float) -> tuple[int, list[int], list[str]]:
    pids = [p.get("pid", 0) for p in _programs_known(cell)]
    hard = _stop_pids(pids, grace_s) if pids else []
    removed = _cleanup(cell)
    return len(pids), hard, removed


def _programs_known(cell: Cell) -> list[dict]:
    """Programs of the cell: those droid-cell started plus any started by hand
    (found through their presence records in /dev/shm)."""
    state = read_state(cell) or {}
    progs = list(state.get("programs", []))
    known = {p["key"] for p in progs}
    prefix = f"droid.{cell.name}.proc."
    for entry in cell_objects(cell.name):
        if entry.startswith(prefix) and entry[len(prefix):] not in known:
            key = entry[len(prefix):]
            try:
                db = Database(db_name(cell.name, "proc", key), PROC_STATUS_LAYOUT, timeout_s=0.2)
            except (NoDatabase, BadInput, RuntimeFailure):
                continue
            try:
                rec = db.read()
            finally:
                db.close()
            words = rec["name"].item().decode(errors="replace").split()
            progs.append({"key": key, "prog": words[0] if words else key, "args": words[1:],
                          "host": "?", "pid": int(rec["pid"])})
    return progs


STATUS_KEYS = {  # droid-cell status --json: one object a line with these keys
    "name": "program and its subunit, e.g. \"droid-remote arm1\"",
    "key": "presence record key: /droid.<cell>.proc.<key>",
    "host": "host the cell file puts it on (\"?\" if started by hand)",
    "pid": "process id",
    "alive": "the pid exists (not a zombie)",
    "state": "starting | ready | stopping | failed | dead",
    "live": "alive, ready and its presence record younger than 2 s",
    "last_tick": "last heartbeat tick it saw (0 if not tick-driven; null without a record)",
    "age_s": "age of its presence record [s]",
    "cycles": "loop cycles (agents: commands served; remotes: replies received)",
    "overruns": "missed deadlines (tick-driven programs: missed ticks)",
    "bad_frames": "malformed messages received and dropped",
    "missed_pct": "share of its periods missed in the last 2 s window [%] (null without a record)",
    "lagging": "it cannot keep its rate: missed_pct >= 5 % (its log says so too)",
    "lateness_max_ms": "its loop's worst wake-up lateness so far [ms] (null without a record)",
    "sched": "fifo | nice | other: the scheduler it runs on now (nice: SCHED_OTHER below nice 0)",
    "cpu_pct": "its measured share of one core since it started [%] (utime + stime over its age)",
}


def measured_cpu(pid: int) -> tuple[str | None, float | None]:
    """(sched, cpu_pct) of a running process from /proc: ``fifo`` / ``nice`` / ``other`` and its
    share of one core since it started [%]; (None, None) if it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        with open("/proc/uptime") as f:
            uptime_s = float(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None, None
    hz = os.sysconf("SC_CLK_TCK")
    # fields after the comm: [0] state ... [11] utime [12] stime [16] nice [19] starttime [38] policy
    nice, policy = int(fields[16]), int(fields[38])
    sched = "fifo" if policy in (os.SCHED_FIFO, os.SCHED_RR) else ("nice" if nice < 0 else "other")
    age_s = uptime_s - int(fields[19]) / hz
    cpu = (int(fields[11]) + int(fields[12])) / hz / age_s * 100.0 if age_s > 0 else 0.0
    return sched, round(cpu, 1)


def restart(cell: Cell, name: str, timeout_s: float) -> Spec:
    """Start one program of the cell again (it must be dead); returns its new Spec."""
    state = read_state(cell)
    if state is None:
        raise RuntimeFailure(f"cell {cell.name!r} is not up (no programs found)")
    found = None
    for fname in sorted(f for f in os.listdir(cell.run_dir) if f.startswith("cell") and f.endswith(".json")):
        with open(cell.run_dir / fname) as f:
            st = json.load(f)
        for p in st.get("programs", []):
            if name in (p["key"], " ".join([p["prog"], *p["args"]])):
                found = (fname, st, p)
    if found is None:
        raise BadInput(f"no program {name!r} in cell {cell.name!r}")
    fname, st, p = found
    if pid_alive(p["pid"]):
        raise RuntimeFailure(f"{name} is still running (pid {p['pid']})")
    _reap()
    spec = Spec(p["key"], p["prog"], list(p["args"]), p["host"])
    log_dir = str(cell.run_dir / "logs")
    started = _start(cell, [spec], log_dir)
    p["pid"] = spec.pid
    p["argv"] = spec.argv
    path = str(cell.run_dir / fname)
    with open(path + ".tmp", "w") as f:
        json.dump(st, f, indent=1)
    os.replace(path + ".tmp", path)
    try:
        _await_ready(started, timeout_s, log_dir)
    except BaseException:
        _stop_pids([spec.pid], STOP_GRACE_S)
        raise
    return spec


def status(cell: Cell) -> list[dict]:
    progs = _programs_known(cell)
    if not progs:
        raise RuntimeFailure(f"cell {cell.name!r} is not up (no programs found)")
    rows = []
    now = time.monotonic_ns()
    for p in progs:
        row = {"name": " ".join([p["prog"], *p["args"]]), "key": p["key"], "host": p["host"],
               "pid": p["pid"], "alive": pid_alive(p["pid"]), "state": "dead", "live": False,
               "last_tick": None, "age_s": None, "cycles": None, "overruns": None, "bad_frames": None,
               "missed_pct": None, "lagging": False, "lateness_max_ms": None, "sched": None, "cpu_pct": None}
        try:
            db = Database(db_name(cell.name, "proc", p["key"]), PROC_STATUS_LAYOUT, timeout_s=0.2)
        except (NoDatabase, BadInput):
            db = None
        if db is not None:
            try:
                rec = db.read()
                row["state"] = PROC_STATE_NAMES.get(int(rec["state"]), "?")
                row["last_tick"] = int(rec["last_tick"])
                row["age_s"] = round((now - int(rec["updated_ns"])) / 1e9, 3)
                row["cycles"] = int(rec["cycles"])
                row["overruns"] = int(rec["overruns"])
                row["bad_frames"] = int(rec["bad_frames"])
                row["missed_pct"] = round(float(rec["missed_pct"]), 1)
                row["lagging"] = bool(rec["lagging"])
                late_ns = int(rec["lateness_max_ns"])
                row["lateness_max_ms"] = None if late_ns == LATENESS_NO_RECORD else round(late_ns / 1e6, 2)
            finally:
                db.close()
        if not row["alive"]:
            row["state"] = "dead"
        else:
            row["sched"], row["cpu_pct"] = measured_cpu(p["pid"])
        row["live"] = bool(row["alive"] and row["state"] == "ready" and row["age_s"] is not None
                           and row["age_s"] < LIVE_AGE_S)
        rows.append(row)
    return rows


@run
def main(argv=None) -> int:
    ap = ArgumentParser(prog=PROG, description="Bring a DROID cell up, report on it, or bring it down.")
    ap.add_argument("--cell", metavar="FILE", default=None,
                    help="cell file (default: $DROID_CELL, else the built-in simulated cell)")
    sp = ap.add_subparsers(dest="cmd", required=True, metavar="{up,status,restart,down}")
    p_up = sp.add_parser("up", help="create the databases and start every program")
    p_up.add_argument("--host", action="append", metavar="HOST",
                      help="start only this host's programs (repeatable; default: all hosts)")
    p_up.add_argument("--timeout", type=timeout_s, default=READY_TIMEOUT_S, metavar="S",
                      help=f"readiness timeout [s] (default {READY_TIMEOUT_S:g})")
    p_up.add_argument("--force", action="store_true",
                      help=f"start a cell whose SCHED_FIFO programs declare more than "
                           f"{RT_BUDGET_PCT_PER_CPU:.0f} %% of one core per CPU (the real-time budget)")
    p_up.add_argument("--replay", metavar="FILE", default=None,
                      help="a replay cell: the Brain's databases only, for droid-replay FILE (docs/observe.md)")
    sp.add_parser("init", help="only create the databases (to start programs by hand)")
    p_rs = sp.add_parser("restart", help="start one dead program of the cell again")
    p_rs.add_argument("name", help="the program as 'status' lists it (e.g. 'droid-servo arm1') or its key")
    p_rs.add_argument("--timeout", type=timeout_s, default=READY_TIMEOUT_S, metavar="S",
                      help=f"readiness timeout [s] (default {READY_TIMEOUT_S:g})")
    p_st = sp.add_parser("status", help="list every program with its pid and liveness")
    p_st.add_argument("--json", action="store_true", help="one JSON object per program, a line each")
    p_dn = sp.add_parser("down", help="stop every program and remove the shared memory")
    p_dn.add_argument("--timeout", type=timeout_s, default=STOP_GRACE_S, metavar="S",
                      help=f"grace period before SIGKILL [s] (default {STOP_GRACE_S:g})")
    for p in sp.choices.values():
        p.add_argument("--cell", metavar="FILE", default=argparse_default(),
                       help="cell file (default: $DROID_CELL, else the built-in simulated cell)")
    args = ap.parse_args(argv)
    cell = load_cell(args.cell)
    use_cell(cell)
    if args.cmd in ("init", "restart") or (args.cmd == "up" and args.replay is None):
        # every class, program and twin registered, before a database or a process is made
        validate_cell(cell)
        from droid.guard.cell import check_guard_homes  # the collision guard's bodies (docs/guard.md)

        check_guard_homes(cell)
    if args.cmd == "up" and args.replay is not None:
        if args.host:
            raise BadInput("--replay brings up the Brain's databases only: no --host")
        up_replay(cell, args.replay)
        print(f"cell {cell.name} up for replay of {args.replay}: Brain databases only (run dir {cell.run_dir})")
        return 0
    if args.cmd == "up":
        hosts = set(args.host) if args.host else None
        if hosts:
            unknown = hosts - set(cell.hosts())
            if unknown:
                raise BadInput(f"unknown host(s) {', '.join(sorted(unknown))} "
                               f"(cell hosts: {', '.join(cell.hosts())})")
        specs = up(cell, hosts, args.timeout, force=args.force)
        print(f"cell {cell.name} up: {len(specs)} programs ready (run dir {cell.run_dir})")
        return 0
    if args.cmd == "restart":
        spec = restart(cell, args.name, args.timeout)
        print(f"cell {cell.name}: {spec.prog} {' '.join(spec.args)} restarted (pid {spec.pid})")
        return 0
    if args.cmd == "init":
        for db in create_databases(cell):
            db.close()
        print(f"cell {cell.name}: databases created")
        return 0
    if args.cmd == "status":
        return print_status(status(cell), args.json)
    n, hard, removed = down(cell, args.timeout)
    msg = f"cell {cell.name} down: {n} programs stopped"
    if hard:
        msg += f" ({len(hard)} needed SIGKILL)"
    print(msg + f", {len(removed)} shared-memory objects removed")
    left = cell_objects(cell.name)
    if left:
        raise RuntimeFailure(f"could not remove {', '.join(left)}")
    return 0


def print_status(rows: list[dict], as_json: bool) -> int:
    """``droid-cell status [--json]``'s output; 0 when every program is live, else 1."""
    for r in rows:
        if as_json:
            print(json.dumps(r))
            continue
        live = "live" if r["live"] else ("STALLED" if r["alive"] else "DEAD")
        if r["live"] and r["lagging"]:
            live = "LAGGING"  # alive and beating, but missing its periods
        tick = "-" if r["last_tick"] is None else r["last_tick"]
        lag = f"  missed {r['missed_pct']:.1f} % of its periods" if r["lagging"] else ""
        cpu = "" if r["cpu_pct"] is None else f"  cpu {r['cpu_pct']:4.1f} % {r['sched']}"
        print(f"{r['name']:<28} pid {r['pid']:>7}  {r['state']:<9} {live:<8} tick {str(tick):<7}{cpu}{lag}")
    return 0 if all(r["live"] for r in rows) else 1


def argparse_default():
    import argparse

    return argparse.SUPPRESS


if __name__ == "__main__":
    sys.exit(main())
