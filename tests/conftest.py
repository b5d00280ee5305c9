"""Shared fixtures.

Every test is checked for leaks (as python-can's autouse fixture does): a
test that leaves a ``droid.*`` shared-memory object or semaphore in /dev/shm,
or a child process running, fails.  Tests that create such objects use a cell
name from :func:`cell_name`, unique per test.
"""
from __future__ import annotations

import os
import re
import subprocess
import time
import uuid
from pathlib import Path

import pytest
from hypothesis import settings

SHM_DIR = "/dev/shm"

# Hypothesis fails an example that takes over 200 ms ("DeadlineExceeded", then "Flaky" when the
# rerun is quick): a verdict on timing, which no test here may give (docs/design.md §8).  Beside the live
# half on two cores an example of test_servo_params.py took 274 ms once and failed the suite.
settings.register_profile("droid", deadline=None)
settings.load_profile("droid")


_MY_CELLS: set[str] = set()  # cell names handed out by this pytest process


def droid_shm_entries() -> set[str]:
    """Names in /dev/shm that belong to cells of this test run (shm objects and semaphores).

    Only cells named through the ``cell_name`` fixture count, so two test runs on
    one machine (developers, CI) do not see each other's objects as leaks."""
    try:
        names = os.listdir(SHM_DIR)
    except FileNotFoundError:
        return set()
    out = set()
    for n in names:
        rest = n[4:] if n.startswith("sem.") else n
        if rest.startswith("droid.") and rest.split(".")[1] in _MY_CELLS:
            out.add(n)
    return out


def child_pids() -> set[int]:
    """PIDs of live (non-zombie) children of this test process."""
    me = os.getpid()
    pids = set()
    try:
        with open(f"/proc/{me}/task/{me}/children") as f:
            pids = {int(p) for p in f.read().split()}
    except OSError:
        return set()
    live = set()
    for pid in pids:
        try:
            with open(f"/proc/{pid}/stat") as f:
                state = f.read().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            live.add(pid)
    return live


LEAK_TAG_ENV = "DROID_TEST_LEAK_TAG"


def tagged_pids(tag: str) -> set[int]:
    """Live processes whose environment carries this test's tag (cell programs started
    by droid-cell run in their own sessions, so they are not our children)."""
    needle = f"{LEAK_TAG_ENV}={tag}".encode()
    found = set()
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            with open(f"/proc/{entry}/environ", "rb") as f:
                if needle not in f.read():
                    continue
            with open(f"/proc/{entry}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    continue
        except OSError:
            continue
        found.add(int(entry))
    return found


def locked_kib() -> int:
    """This process's locked memory [KiB] (VmLck of /proc/self/status)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmLck:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


#: the pytest process's own nice level, as it started (scripts/test.sh may run it niced)
PYTEST_NICE = os.getpriority(os.PRIO_PROCESS, 0)


def scheduler_leak() -> str | None:
    """What a test left of a real-time program in the pytest process itself (None: nothing).

    A program's ``main()`` called in-process switches the caller to SCHED_FIFO and locks its
    memory (:func:`droid.brain.runtime.rt.try_sched_fifo`).  Left so, every later test -- and every
    process it starts, cell programs included -- ran at FIFO priority: sixteen programs
    starting at once on two cores then set off the kernel's RT throttling and latched the
    arms' watchdogs (issue 16).  The pytest process must stay on the normal scheduler."""
    leaks = []
    if os.sched_getscheduler(0) != os.SCHED_OTHER:
        leaks.append(f"scheduling policy {os.sched_getscheduler(0)} (SCHED_FIFO=1), "
                     f"priority {os.sched_getparam(0).sched_priority}")
    if os.getpriority(os.PRIO_PROCESS, 0) < PYTEST_NICE:  # a "nice" program's level (droid.brain.runtime.rt.NICE_LEVEL)
        leaks.append(f"nice {os.getpriority(os.PRIO_PROCESS, 0)}")
    kib = locked_kib()
    if kib:
        leaks.append(f"{kib} KiB of locked memory")
    return " and ".join(leaks) or None


def cell_logs(request) -> list[str]:
    """Program logs of a cell that ran under this test's tmp_path (``**/logs/*.log``)."""
    tmp = getattr(request.node, "funcargs", {}).get("tmp_path")
    return sorted(str(p) for p in tmp.glob("**/logs/*.log")) if tmp is not None else []


#: The funcarg the session's shared homed cell is handed out by (:func:`homed_sim_cell`): its
#: program logs live beside its cell file, not under the test's tmp_path.
SHARED_CELL_ARG = "homed_sim_cell"


def log_dirs(item) -> list:
    """Where a test's cell logs are: its tmp_path, and the folder of a shared cell it used."""
    args = getattr(item, "funcargs", {})
    dirs = [args["tmp_path"]] if args.get("tmp_path") is not None else []
    if args.get(SHARED_CELL_ARG) is not None:
        dirs.append(args[SHARED_CELL_ARG].parent)
    return dirs


@pytest.fixture(autouse=True)
def no_leaks(monkeypatch, request):
    """Fail a test that leaves droid shm objects, semaphores or processes behind, or the
    pytest process on a real-time scheduler or with locked memory (:func:`scheduler_leak`)."""
    from droid.brain.runtime.rt import normal_scheduler

    tag = uuid.uuid4().hex
    monkeypatch.setenv(LEAK_TAG_ENV, tag)
    shm_before = droid_shm_entries()
    kids_before = child_pids()
    yield
    sched = scheduler_leak()
    if sched:
        normal_scheduler()  # do not let one leak run every later test at FIFO priority
    deadline = time.monotonic() + 5.0
    while True:
        leaked_shm = droid_shm_entries() - shm_before
        leaked_kids = (child_pids() - kids_before) | tagged_pids(tag)
        if not (leaked_shm or leaked_kids) or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    for pid in leaked_kids:  # do not let one leak cascade into later tests
        try:
            os.kill(pid, 9)
        except OSError:
            pass
    for name in leaked_shm:
        try:
            os.unlink(os.path.join(SHM_DIR, name))
        except OSError:
            pass
    assert not leaked_shm, f"test left shared-memory objects behind: {sorted(leaked_shm)}"
    assert not leaked_kids, f"test left child processes running: {sorted(leaked_kids)}"
    assert sched is None, f"test left the pytest process with {sched}"
    if not request.node.get_closest_marker("integration"):
        logs = cell_logs(request)
        assert not logs, (f"this test ran a cell of processes ({logs[0]}) but is not marked "
                          "integration: mark it, so that scripts/test.sh never runs it beside "
                          "another live cell")


def new_cell_name() -> str:
    """A cell name unique to this pytest run (so shm names never collide), counted as ours by
    :func:`droid_shm_entries`."""
    name = f"t{uuid.uuid4().hex[:10]}"
    _MY_CELLS.add(name)
    return name


@pytest.fixture
def cell_name(request) -> str:
    """A cell name unique to this test (so shm names never collide)."""
    return new_cell_name()


@pytest.fixture
def sim_cell(tmp_path, cell_name):
    """The built-in simulated cell (renamed, run dir in tmp) brought up for the test and
    always brought down after it; yields the cell file's path."""
    from tests.brain.cellutil import cell_up, make_cell_file

    with cell_up(make_cell_file(tmp_path, cell_name), cell_name) as path:
        yield path


@pytest.fixture
def host_pair():
    """Two network namespaces joined by a veth pair (droid.faults.netns), removed after the
    test; fails the test if any namespace or veth it made is left behind."""
    from droid.faults import netns

    why = netns.available()
    if why is not None:
        pytest.skip(f"no network namespaces here: {why}")
    before = set(netns.leftovers())
    hp = netns.HostPair(subnet=int(uuid.uuid4().int % 200) + 20)
    hp.create()
    try:
        yield hp
    finally:
        hp.destroy()
        left = set(netns.leftovers()) - before
        assert not left, f"test left network namespaces or links behind: {sorted(left)}"


LOG_TAIL_LINES = 25


def cell_log_lines(item):
    """(path, lines) of every program log of a test's cell (:func:`log_dirs`), in name order."""
    for log in sorted(p for d in log_dirs(item) for p in d.glob("**/logs/*.log")):
        try:
            yield log, log.read_text(errors="replace").splitlines()
        except OSError:
            continue


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """A live-cell test that fails shows the tail of every program's log of its cell
    (``<tmp_path>/**/logs/*.log``): a failure one run in many is diagnosed from the
    run that had it, not from a rerun (issue 16)."""
    outcome = yield
    report = outcome.get_result()
    if report.passed or report.skipped:
        return
    parts = []
    for log, lines in cell_log_lines(item):
        if lines:
            parts.append(f"--- {log} (last {min(len(lines), LOG_TAIL_LINES)} "
                         f"of {len(lines)} lines)\n" + "\n".join(lines[-LOG_TAIL_LINES:]))
    stalls = stall_summary(item)
    if stalls:
        report.sections.append(("stalls", stalls))
    if parts:
        report.sections.append(("cell logs", "\n".join(parts)))


#: What a program's log says when the host stalled it (droid-sim's slow steps and slipped clock,
#: a loop's rate watch, the servo's brake, the watchdog's latch): issue 40 item 5
STALL_LINE = re.compile(r"took \d+ ms for one|stalled \d+ ms|slipped \d+ ms|LAGGING|missed [\d.]+ % of its"
                        r"|ran out of commands|braking|watchdog timers expired|catching up")


def kernel_rt_throttling() -> str:
    """Whether the kernel's RT throttling struck: its log line (only the first of a boot is
    printed) and, where debugfs is mounted, each CPU's real-time time used this period."""
    out = []
    try:
        dmesg = subprocess.run(["dmesg"], capture_output=True, text=True, timeout=5).stdout
        hits = [ln for ln in dmesg.splitlines() if "RT throttling" in ln]
        out.append(f"kernel log: {hits[-1].strip()}" if hits else "kernel log: no RT throttling this boot")
    except (OSError, subprocess.SubprocessError):
        out.append("kernel log: unreadable")
    try:
        text = Path("/sys/kernel/debug/sched/debug").read_text()
        used = re.findall(r"\.rt_time\s*:\s*([\d.]+)", text)
        throttled = re.findall(r"\.rt_throttled\s*:\s*(\d+)", text)
        out.append(f"rt_time this period per CPU [ms]: {', '.join(used)}; throttled now: {', '.join(throttled)}")
    except OSError:
        pass
    return "\n".join(out)


def stall_summary(item) -> str:
    """The stall lines of every program log of the failed test's cell, each with its program,
    and the kernel's RT throttling: a live test lost to a host stall says so in its report."""
    found = []
    for log, lines in cell_log_lines(item):
        found += [f"{log.stem}: {ln.strip()}" for ln in lines if STALL_LINE.search(ln)][-STALL_LINES_EACH:]
    if not found and not log_dirs(item):
        return ""
    head = f"{len(found)} stall line(s) in the cell's logs" if found else "no stall line in the cell's logs"
    return "\n".join([head, *found, kernel_rt_throttling()])


STALL_LINES_EACH = 10  # the last stall lines kept per program log


HOMED_ARMS = ("arm1", "gmf1")  # the built-in sim cell's arms, homed at once

#: Markers that place a test among those on the session's shared homed cell
#: (:func:`pytest_collection_modifyitems`): first, while both arms still stand where homing left
#: them; last, because the test breaks the cell.
SHARED_FIRST, SHARED_LAST = "shared_cell_first", "shared_cell_last"


def pytest_collection_modifyitems(config, items):
    """Run every test on the shared homed cell (:func:`shared_sim_cell`) after all the others,
    in one block: the cell is then up only while its own tests run -- never beside another
    test's cell on this two-core machine -- and comes down at the session's end, right after
    them.  Within the block: tests marked ``shared_cell_first``, then the rest in the order
    collected, then those marked ``shared_cell_last`` (they leave the cell broken)."""
    def rank(item):
        if SHARED_CELL_ARG not in getattr(item, "fixturenames", ()):
            return 0
        if item.get_closest_marker(SHARED_FIRST):
            return 1
        return 3 if item.get_closest_marker(SHARED_LAST) else 2

    items[:] = sorted(items, key=rank)  # sorted() is stable: the collected order within a rank


@pytest.fixture(scope="session")
def shared_sim_cell(tmp_path_factory):
    """The built-in simulated cell brought up once for the session and both arms homed (issue 28
    item 5: live tests share a homed cell where a test does not need a fresh one); brought
    down after the session's last test, with the same proofs as a test's own cell: ``down``
    succeeds, nothing of the cell stays in /dev/shm, and none of its programs runs on.

    Its programs carry a tag of their own (not a test's), so each test's leak check sees them
    neither as its own nor as leaked; they are checked here instead.  Homing costs about 30 s
    of real time a cell, which is what the sharing saves.  Tests use it through
    :func:`homed_sim_cell`, which checks it is still whole before each test; the tests that use
    it run last, in one block (:func:`pytest_collection_modifyitems`)."""
    from tests.brain.cellutil import brought_down, droid, home_at_once, make_cell_file

    name = new_cell_name()
    path = make_cell_file(tmp_path_factory.mktemp("shared"), name)
    tag, old = uuid.uuid4().hex, os.environ.get(LEAK_TAG_ENV)
    try:
        with brought_down(path, name):
            os.environ[LEAK_TAG_ENV] = tag
            out = droid("droid.brain.runtime.launcher", "up", "--cell", str(path), timeout=120)
            _restore_env(LEAK_TAG_ENV, old)
            assert out.returncode == 0, out.stdout + out.stderr
            home_at_once(path, HOMED_ARMS)
            yield path
    finally:
        _restore_env(LEAK_TAG_ENV, old)
        deadline = time.monotonic() + 5.0
        while tagged_pids(tag) and time.monotonic() < deadline:
            time.sleep(0.05)
        left = tagged_pids(tag)
        for pid in left:
            os.kill(pid, 9)
        assert not left, f"the shared cell {name} left processes running: {sorted(left)}"


def _restore_env(key: str, old: str | None) -> None:
    if old is None:
        os.environ.pop(key, None)
    else:
        os.environ[key] = old


@pytest.fixture
def homed_sim_cell(shared_sim_cell):
    """The session's shared homed cell (:func:`shared_sim_cell`), checked whole before the test:
    every program live, both arms homed, fresh and without a fault -- a test that broke it fails
    the next one here, naming what it left, rather than somewhere in the middle of a run.  The
    check reads the cell's state and the Brain's Status records in this process (no program
    started: it runs before each of many tests)."""
    from droid.brain.cell.cellfile import load_cell
    from droid.brain.db.databases import open_brain
    from droid.brain.runtime.launcher import status
    from tests.brain.cellutil import wait_for

    cell = load_cell(shared_sim_cell)
    dead = [r["name"] for r in status(cell) if not r["live"]]
    assert not dead, f"an earlier test left the shared cell with programs not live: {dead}"

    def whole(arm):
        with open_brain(cell, cell.subunit(arm), "status") as st:
            r = st.read()
        return {k: int(r[k]) for k in ("homed", "fault", "stale")}

    for arm in HOMED_ARMS:
        try:  # a Status stale for a moment (a host stall) is waited out, not a verdict
            wait_for(lambda: (lambda s: s["homed"] == 1 and not s["fault"] and not s["stale"])(whole(arm)),
                     timeout=10, what=f"{arm} homed, fresh, no fault")
        except AssertionError:
            raise AssertionError(f"an earlier test left {arm} so: {whole(arm)}") from None
    return shared_sim_cell
