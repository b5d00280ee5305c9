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
(:class:`droid.brain.registry.Twin`: type -> ``"module:factory"``), imported only
when a cell asks for it (python-can's lazy backend table); :data:`DEVICE_TYPES`
is the registry's view ``type -> (module, factory)``.  A factory is called as
``factory(world, name, options)`` and returns a :class:`Device`; it may look up
devices declared before it in ``world.devices`` (the camera needs both arms).
"""
from __future__ import annotations

import sys
import time
from typing import Any

from droid.brain.registry import program, registry, twin_factory, validate_cell
from droid.brain.program import Presence, Stop, close_all, notify_ready, open_cell, parser, presence_key
from droid.brain.rt import PeriodicTimer, try_sched_fifo
from droid.cli import BadInput, RuntimeFailure, file_number, run, seed_int
from droid.numbers import SEED, Range
from droid.sim.device import Device

PROG = "droid-sim"
DEFAULT_RATE_HZ = program(PROG).rate_hz  # the world's default step rate [Hz], declared with droid-sim



def __getattr__(name: str):
    # DEVICE_TYPES (type -> (module, factory)) is a view of the device registry: each device
    # package declares its twins in its device.py (droid.brain.registry.Twin)
    if name == "DEVICE_TYPES":
        from droid.brain.registry import device_types

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

#: World time integrated at most per wake-up [s], and the most it owes after a stall
#: before it drops the rest [s]; see main().
MAX_STEP_PER_WAKE_S = 0.004
MAX_OWED_S = 0.1


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
        timer = PeriodicTimer(int(round(1e9 / rate)))
        presence.ready()
        notify_ready(args.ready_fd)
        dt = 1.0 / rate
        per_wake = max(1, int(MAX_STEP_PER_WAKE_S * rate))  # steps at most between two servo reads
        max_owed = max(per_wake, int(MAX_OWED_S * rate))
        owed = slipped = 0
        told_at = -int(rate)
        steps = StepTimes()
        while not Stop.requested:
            n = timer.wait(0.5)
            if not n:
                continue
            # After an overrun the world does not integrate the whole stall at once: a
            # 20 ms lump moved a fast joint > 3000 counts between two servo reads, which
            # the servo rightly takes for an encoder glitch (ENCODER_JUMP) -- physics never
            # stalls on real hardware.  It catches up a few steps per wake-up instead
            # (1 ms wake-ups: it gains ~3 ms a ms) and drops what it owes beyond
            # MAX_OWED_S (the world's clock slips: the robots pause with it) -- issue 16.
            owed += n
            if owed > max_owed:
                slipped += owed - max_owed
                if timer.cycles >= told_at + rate:  # at most once a second: when, and how far
                    told_at = timer.cycles
                    print(f"{PROG}: stalled {n * dt * 1e3:.0f} ms at step {timer.cycles}: the world's clock "
                          f"slipped {(owed - max_owed) * dt * 1e3:.0f} ms", file=sys.stderr, flush=True)
                owed = max_owed
            t0 = time.perf_counter_ns()
            for _ in range(min(owed, per_wake)):
                world.advance(dt)
            steps.add(time.perf_counter_ns() - t0, timer.lateness_ns)
            owed -= min(owed, per_wake)
            presence.beat(0, timer.cycles, timer.overruns, timer.lateness_max_ns)
        print(f"{PROG}: {steps.summary()}", file=sys.stderr)
        if slipped:
            print(f"{PROG}: the world's clock slipped {slipped * dt * 1e3:.0f} ms over {timer.cycles} steps "
                  f"(stalls it could not catch up within {MAX_OWED_S * 1e3:.0f} ms)", file=sys.stderr)
    finally:
        close_all(timer, world, presence)
    return 0


if __name__ == "__main__":
    sys.exit(main())
