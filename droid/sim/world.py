"""droid-sim: the world behind the drivers — the hardware twins of the cell (docs/design.md §1).

It hosts the simulated devices the cell file asks for and steps them on
absolute deadlines at ``[world] rate_hz``.  DROID programs never import this
package: they reach the twins only through their device drivers (a shared-memory
register map, a pseudo-terminal, ...), by the URLs in the cell file.

Devices are declared in the cell file, in stepping order::

    [world.devices.arm1]          # the device's name
    type = "reis_vme"             # a twin type of the device registry
    ...                           # options of that type

Each device package declares its twins in its ``device.py``
(:class:`droid.brain.cell.registry.Twin`: type -> ``"module:factory"``), imported only
when a cell asks for it (python-can's lazy backend table); :data:`DEVICE_TYPES`
is the registry's view ``type -> (module, factory)``.  A factory is called as
``factory(world, name, options)`` and returns a :class:`Device`; it may look up
devices declared before it in ``world.devices`` (the camera needs both arms).
"""
from __future__ import annotations

import sys
import time
from typing import Any

from droid.brain.cell.registry import program, registry, twin_factory, validate_cell
from droid.brain.runtime.program import Presence, Stop, close_all, notify_ready, open_cell, parser, presence_key
from droid.brain.runtime.rt import PeriodicTimer, try_sched_fifo
from droid.cli import BadInput, RuntimeFailure, file_number, run, seed_int
from droid.numbers import SEED, Range
from droid.sim.device import Device, wake_hz_of

PROG = "droid-sim"
DEFAULT_RATE_HZ = program(PROG).rate_hz  # the world's default step rate [Hz], declared with droid-sim



def __getattr__(name: str):
    # DEVICE_TYPES (type -> (module, factory)) is a view of the device registry: each device
    # package declares its twins in its device.py (droid.brain.cell.registry.Twin)
    if name == "DEVICE_TYPES":
        from droid.brain.cell.registry import device_types

        return device_types()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class World:
    """The simulated devices of one cell, stepped in declaration order."""

    def __init__(self, cell, seed: int = 0) -> None:
        self.cell = cell
        self.seed = seed
        self.devices: dict[str, Device] = {}
        self._owed_s: dict[str, float | None] = {}  # world time each device is owed [s] (Device.step_s)
        self.t_s = 0.0

    #: a device step longer than this is reported (it stalls every device of the world) [s]
    SLOW_STEP_S = 0.02

    def add(self, name: str, dev: Device) -> None:
        self.devices[name] = dev
        self._owed_s[name] = None  # never advanced: the world's first step advances it (power-up)

    def advance(self, dt_s: float) -> None:
        """One world step of ``dt_s`` [s]: each device is advanced when the world time it is owed
        reaches its ``step_s`` (every step for 0), by all of that time -- so a camera, a serial
        line or an F/T stream costs the world its own rate, not the arms' 1 kHz.  Every device
        is advanced on the world's first step (the power-up: its registers, ports and sockets)."""
        clock = time.perf_counter
        t1 = clock()
        owed = self._owed_s
        for name, dev in self.devices.items():
            before = owed[name]
            due = dt_s if before is None else before + dt_s
            if before is not None and due < dev.step_s - 1e-9:
                owed[name] = due
                continue
            owed[name] = 0.0
            t0 = t1  # one clock reading a device: each one's end is the next one's start
            dev.advance(due)
            t1 = clock()
            took = t1 - t0
            if took > self.SLOW_STEP_S:
                print(f"{PROG}: device {name} took {took * 1e3:.0f} ms for one {due * 1e3:g} ms step "
                      f"at world time {self.t_s:.3f} s", file=sys.stderr, flush=True)
        self.t_s += dt_s

    def steps(self, n: int, dt_s: float) -> None:
        """``n`` world steps of ``dt_s`` [s] back to back (one wake-up's): the same as ``n`` calls
        of :meth:`advance` (every device sees its 1 ms steps as ever)."""
        advance = self.advance
        for _ in range(n):
            advance(dt_s)

    def steps_per_wake(self, rate_hz: float) -> int:
        """How many world steps of ``1 / rate_hz`` the real-time world takes per wake-up: the
        most that still wakes it at least as often as its fastest device needs
        (:func:`droid.sim.device.wake_hz_of`: an arm twin at droid-servo's 500 Hz, a camera or
        a serial line at its own step).  2 for the built-in cell at 1 kHz; 1 when a device
        needs every step or the world has none (docs/architecture.md "The world's rates")."""
        need = max((wake_hz_of(dev, rate_hz) for dev in self.devices.values()), default=0.0)
        if need <= 0.0:
            return 1
        return max(1, int(rate_hz / need + 1e-9))

    def close(self) -> None:
        for dev in reversed(list(self.devices.values())):
            try:
                dev.close()
            except Exception as exc:  # keep closing the others
                print(f"{PROG}: closing {dev.name}: {exc}", file=sys.stderr)


def build_world(cell, seed: int | None = None) -> World:
    """Build the devices the cell file declares under ``[world.devices]``."""
    if seed is None:
        seed = file_number(cell.world.get("seed", 0), SEED, f"{cell.path}: [world]", "seed")
    w = World(cell, int(seed))
    devices: dict[str, Any] = cell.world.get("devices", {})
    if not isinstance(devices, dict):
        raise BadInput(f"{cell.path}: [world.devices] must be a table of device tables")
    try:
        for name, opts in devices.items():
            if not isinstance(opts, dict) or "type" not in opts:
                raise BadInput(f"{cell.path}: [world.devices.{name}] needs a 'type'")
            typ = opts["type"]
            reg = registry()
            if typ not in reg.twins:
                raise BadInput(f"{cell.path}: [world.devices.{name}] "
                               f"{reg.unknown('type', typ, sorted(reg.twins))}")
            fn = twin_factory(typ)
            w.add(name, fn(w, name, {k: v for k, v in opts.items() if k != "type"}))
    except BaseException:
        w.close()
        raise
    return w


def truth_main(argv) -> int:
    """``droid-sim truth ARM --json [--cell FILE]``: the running world's truth about one arm."""
    import json

    import posix_ipc

    from droid.sim.truth import TruthDoor, door_name, truth_dict

    ap = parser(f"{PROG} truth", "Print an arm's true joint angles and wrist-centre position (the world's truth).")
    ap.add_argument("arm", help="the arm's subunit name (e.g. arm1)")
    ap.add_argument("--json", action="store_true", help="one JSON object (the only format)")
    args = ap.parse_args(argv)
    cell = open_cell(args)
    sub = cell.subunit(args.arm)  # BadInput for an unknown subunit
    if not getattr(sub, "robot", None):
        raise BadInput(f"{args.arm!r} is not an arm")
    try:
        door = TruthDoor.open(door_name(cell.name, sub.name))
    except posix_ipc.ExistentialError:
        raise RuntimeFailure(f"no truth for {sub.name}: droid-sim is not running cell {cell.name!r} "
                             f"or simulates no {sub.name}") from None
    try:
        got = door.read()
    finally:
        door.close()
    if got is None:
        raise RuntimeFailure(f"no truth for {sub.name} yet (the world has not stepped)")
    t_s, q, wcp = got
    print(json.dumps(truth_dict(sub.name, t_s, q, wcp)))
    return 0


#: The world's step rates ([world] rate_hz) [Hz].
WORLD_RATE_HZ = Range(1.0, 10000.0, "Hz")

#: A wake-up integrates at most this many of its own periods of world time (it catches up
#: after a stall at 3 periods a period: 4 ms a 1 ms wake-up, 8 ms a 2 ms one -- at most 8 ms
#: between two of droid-servo's 2 ms reads either way), and the world owes at most
#: MAX_OWED_S [s] after a stall before it drops the rest (its clock slips); see CatchUp.
CATCH_UP_PERIODS = 4
MAX_OWED_S = 0.1


class CatchUp:
    """The world steps the real-time world takes at each wake-up (issue 16, issue 40 item 2).

    Each period of the wake-up timer owes ``steps_per_wake`` world steps.  A wake-up takes all
    it owes up to ``per_wake`` steps (bounded: a stall is not integrated in one lump -- a 20 ms
    lump moved a fast joint > 3000 counts between two servo reads, which the servo rightly
    takes for an encoder glitch, ENCODER_JUMP); what it owes beyond ``max_owed`` steps is
    dropped (``slipped``: the world's clock slips, the robots pause with it).  Nothing else is
    lost or added: ``taken + owed + slipped == steps_per_wake * periods`` after every wake-up,
    and every step taken is the world's ordinary step (the plant's exact step of 1 ms), so a
    plant that caught up holds the bits of one that never stalled."""

    def __init__(self, steps_per_wake: int, per_wake: int, max_owed: int) -> None:
        if not (1 <= steps_per_wake <= per_wake <= max_owed):
            raise ValueError(f"need 1 <= steps_per_wake ({steps_per_wake}) <= per_wake ({per_wake}) "
                             f"<= max_owed ({max_owed}) [steps]")
        self.steps_per_wake, self.per_wake, self.max_owed = steps_per_wake, per_wake, max_owed
        self.periods = self.taken = self.owed = self.slipped = 0

    @classmethod
    def for_rate(cls, rate_hz: float, steps_per_wake: int) -> "CatchUp":
        """The real-time world's: CATCH_UP_PERIODS wake-up periods a wake-up, MAX_OWED_S owed."""
        per_wake = CATCH_UP_PERIODS * steps_per_wake
        return cls(steps_per_wake, per_wake, max(per_wake, int(MAX_OWED_S * rate_hz)))

    def wake(self, periods: int) -> tuple[int, int]:
        """A wake-up after ``periods`` (>= 1) timer periods: ``(steps to take now, steps dropped)``."""
        self.periods += periods
        self.owed += periods * self.steps_per_wake
        dropped = max(0, self.owed - self.max_owed)
        if dropped:
            self.slipped += dropped
            self.owed = self.max_owed
        k = min(self.owed, self.per_wake)
        self.owed -= k
        self.taken += k
        return k, dropped


class StepTimes:
    """The real-time world's wake-ups, counted: a histogram of the time each one's steps took
    (10 us bins up to 50 ms) and how many woke 20 ms late or more -- droid-sim's log says at exit
    ``N wake-ups: steps p50 .. p99 .. max .. us; K woke >= 20 ms late`` (issue 40's targets)."""

    BIN_NS = 10_000
    BINS = 5000
    LATE_NS = 20_000_000

    def __init__(self) -> None:
        self.hist = [0] * self.BINS
        self.n = self.late = self.max_ns = 0

    def add(self, took_ns: int, lateness_ns: int) -> None:
        self.hist[min(took_ns // self.BIN_NS, self.BINS - 1)] += 1
        self.n += 1
        self.max_ns = max(self.max_ns, took_ns)
        self.late += lateness_ns >= self.LATE_NS

    def quantile_us(self, q: float) -> float:
        """The upper edge of the bin holding quantile ``q`` [us] (0 with no wake-up)."""
        want, seen = q * self.n, 0
        for k, c in enumerate(self.hist):
            seen += c
            if c and seen >= want:
                return (k + 1) * self.BIN_NS / 1e3
        return 0.0

    def summary(self) -> str:
        return (f"{self.n} wake-ups: steps p50 {self.quantile_us(0.5):.0f} us, p99 {self.quantile_us(0.99):.0f} us, "
                f"max {self.max_ns / 1e3:.0f} us; {self.late} woke >= {self.LATE_NS // 1_000_000} ms late")


def serve(world, timer, catch_up: CatchUp, dt_s: float, steps: StepTimes, stop, beat=None,
          clock_ns=time.perf_counter_ns, log=None) -> CatchUp:
    """The real-time world's loop (``main``): wait for ``timer`` (a :class:`PeriodicTimer` of
    ``catch_up.steps_per_wake`` world steps a period, or a fake with ``wait``, ``cycles`` and
    ``lateness_ns``), take the world steps of ``dt_s`` [s] that ``catch_up`` says, record the
    wake-up in ``steps``, call ``beat()``; until ``stop()``.  After a stall the world does not
    integrate the whole stall at once: it catches up a few periods per wake-up and drops what it
    owes beyond MAX_OWED_S, saying so at most once a second of wake-ups (issue 16)."""
    log = sys.stderr if log is None else log
    period_ms = catch_up.steps_per_wake * dt_s * 1e3
    wake_hz = 1e3 / period_ms
    told_at = None
    while not stop():
        n = timer.wait(0.5)
        if not n:
            continue
        k, dropped = catch_up.wake(n)
        if dropped and (told_at is None or timer.cycles >= told_at + wake_hz):  # when, and how far
            told_at = timer.cycles
            print(f"{PROG}: stalled {n * period_ms:.0f} ms at wake-up {timer.cycles}: the world's clock "
                  f"slipped {dropped * dt_s * 1e3:.0f} ms", file=log, flush=True)
        t0 = clock_ns()
        world.steps(k, dt_s)
        steps.add(clock_ns() - t0, timer.lateness_ns)
        if beat is not None:
            beat()
    return catch_up


@run
def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "truth":
        return truth_main(argv[1:])
    if argv and argv[0] == "lockstep":
        from droid.sim.lockstep_cell import lockstep_main

        return lockstep_main(argv[1:], f"{PROG} lockstep")
    ap = parser(PROG, "Run the simulated hardware of a cell (robots, controllers, sensors). "
                      "'droid-sim truth ARM --json' prints an arm's ground truth from the running world; "
                      "'droid-sim lockstep CELL --seconds S' runs the whole cell in lockstep (virtual time).")
    ap.add_argument("--seed", type=seed_int, default=None, help="random seed (default: the cell file's)")
    args = ap.parse_args(argv)
    cell = open_cell(args)
    validate_cell(cell)  # every subunit's class, programs and twin registered, before anything starts
    rate = file_number(cell.world.get("rate_hz", DEFAULT_RATE_HZ), WORLD_RATE_HZ, f"{cell.path}: [world]", "rate_hz")
    Stop.install()
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    presence = Presence(cell.name, presence_key(PROG), PROG)
    world = None
    timer = None
    try:
        world = build_world(cell, args.seed)
        world.advance(1.0 / rate)  # power up: every register holds a real value before anyone reads
        spw = world.steps_per_wake(rate)  # world steps a wake-up: 2 for the built-in cell (the servo's 500 Hz)
        timer = PeriodicTimer(int(round(1e9 * spw / rate)))
        presence.ready()
        notify_ready(args.ready_fd)
        steps = StepTimes()
        catch_up = serve(world, timer, CatchUp.for_rate(rate, spw), 1.0 / rate, steps,
                         lambda: Stop.requested,
                         lambda: presence.beat(0, timer.cycles, timer.overruns, timer.lateness_max_ns))
        print(f"{PROG}: {steps.summary()} ({spw} world step(s) of {1e3 / rate:g} ms a wake-up)", file=sys.stderr)
        if catch_up.slipped:
            print(f"{PROG}: the world's clock slipped {catch_up.slipped * 1e3 / rate:.0f} ms over "
                  f"{catch_up.taken + catch_up.slipped} steps (stalls it could not catch up within "
                  f"{MAX_OWED_S * 1e3:.0f} ms)", file=sys.stderr)
    finally:
        close_all(timer, world, presence)
    return 0


if __name__ == "__main__":
    sys.exit(main())
