"""Lockstep: every core and the world stepped in one process on virtual time (docs/design.md §2).

The same cores that run as separate real-time processes run here as tasks of a
:class:`Scheduler`, each at its own rate, on a virtual clock in integer
nanoseconds.  Nothing sleeps and nothing reads a wall clock, so a trial is as
fast as the arithmetic and gives the same numbers every run for a seed.

The heartbeat is the common time base: :meth:`Scheduler.on_tick` tasks are
called once per heartbeat tick with the tick number (thesis §3.2), while
:meth:`Scheduler.every` tasks run at their own rate (the 500 Hz servo, the
1-2 kHz world, the 120 Hz encoder program) with the virtual time.

Due times are ``start + round(k * 1e9 / rate)`` so rates that do not divide a
second in whole nanoseconds (60 Hz) never drift.  Tasks due at the same
instant run in ``order`` (lower first), then in registration order; the
conventional orders are :data:`ORDER_WORLD` < :data:`ORDER_DEVICE` <
:data:`ORDER_HEARTBEAT` < :data:`ORDER_TASK`, so a cycle sees the world as it
is at that instant.
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass
from typing import Callable

ORDER_WORLD = 0  # plants, controllers, cameras: the physics first
ORDER_DEVICE = 10  # device-level programs: servo, encoder reader, sensor program
ORDER_HEARTBEAT = 20  # the heartbeat tick and everything driven by it
ORDER_TASK = 30


_K_EXACT = 1 << 20  # below this many calls a whole-ns period's k * period_ns is exact (see Task)


@dataclass
class Task:
    name: str
    rate_hz: float
    fn: Callable[[int], None]
    order: int
    start_ns: int
    k: int = 0  # calls made
    enabled: bool = True
    period_ns: int = 0  # the period when it is a whole number of ns (500 Hz, 1 kHz), else 0

    def __post_init__(self) -> None:
        period = 1e9 / self.rate_hz
        if period == int(period) and period * (1 << 20) < 2.0 ** 53:  # k * period exact in floats
            self.period_ns = int(period)

    def due(self, k: int) -> int:
        if self.period_ns and k < _K_EXACT:  # the same value as the rounded product, in ints
            return self.start_ns + k * self.period_ns
        return self.start_ns + int(round(k * 1e9 / self.rate_hz))


class Scheduler:
    """Virtual-time scheduler with the heartbeat as the common time base."""

    def __init__(self, heartbeat_hz: float = 60.0) -> None:
        if not heartbeat_hz > 0:
            raise ValueError("heartbeat rate must be > 0 Hz")
        self.t_ns = 0
        self.tick = 0
        self.heartbeat_hz = heartbeat_hz
        # (due_ns, order, seq, task): plain tuples compare in C (seq is unique, so a task is
        # never compared) -- a dataclass's __lt__ cost as much as some tasks (issue 13 item 6)
        self._heap: list[tuple[int, int, int, Task]] = []
        self._seq = 0
        self._running = False  # inside run_until
        self._tick_fns: list[tuple[int, int, str, Callable[[int], None]]] = []
        self.tasks: dict[str, Task] = {}
        self.every(heartbeat_hz, self._heartbeat, "heartbeat", order=ORDER_HEARTBEAT, phase_ns=None)

    def every(self, rate_hz: float, fn: Callable[[int], None], name: str, *, order: int = ORDER_DEVICE,
              phase_ns: int | None = 0) -> Task:
        """Call ``fn(t_ns)`` at ``rate_hz`` from now (+ ``phase_ns``); returns the task."""
        if not rate_hz > 0:
            raise ValueError(f"{name}: rate must be > 0 Hz")
        if name in self.tasks:
            raise ValueError(f"task {name!r} already scheduled")
        start = self.t_ns + (int(round(1e9 / rate_hz)) if phase_ns is None else phase_ns)
        task = Task(name, float(rate_hz), fn, order, start)
        self.tasks[name] = task
        self._push(task)
        return task

    def on_tick(self, fn: Callable[[int], None], name: str, *, order: int = ORDER_HEARTBEAT) -> None:
        """Call ``fn(tick)`` on every heartbeat tick, in ``order``."""
        self._seq += 1
        self._tick_fns.append((order, self._seq, name, fn))
        self._tick_fns.sort(key=lambda e: (e[0], e[1]))

    def remove(self, name: str) -> None:
        """Stop a task (e.g. a program that 'dies' in a fault-injection test)."""
        if name in self.tasks:
            self.tasks.pop(name).enabled = False
        self._tick_fns = [e for e in self._tick_fns if e[2] != name]

    def _push(self, task: Task) -> None:
        self._seq += 1
        heapq.heappush(self._heap, (task.due(task.k), task.order, self._seq, task))

    def _heartbeat(self, t_ns: int) -> None:
        self.tick += 1
        for _, _, _, fn in list(self._tick_fns):
            fn(self.tick)

    def run_until(self, t_end_ns: int) -> None:
        """Run every task due at or before ``t_end_ns`` [ns], then set the clock there.

        The due task's entry stays at the heap's top while it runs and is then replaced by its
        next one in one sift (``heapreplace``) -- unless the task scheduled or removed something
        that moved it (then it is popped as before).  The keys (due, order, seq) are unique, so
        the tasks run in the same order whatever the heap's shape.  A task must not run the
        scheduler itself (RuntimeError)."""
        if self._running:
            raise RuntimeError("a scheduler task ran the scheduler (run_until inside a task)")
        self._running = True
        try:
            self._run(t_end_ns)
        finally:
            self._running = False
        self.t_ns = max(self.t_ns, t_end_ns)

    def _run(self, t_end_ns: int) -> None:
        heap = self._heap
        pop, replace = heapq.heappop, heapq.heapreplace
        while heap and heap[0][0] <= t_end_ns:
            entry = heap[0]
            due_ns, order, _, task = entry
            if not task.enabled:
                pop(heap)
                continue
            self.t_ns = due_ns
            try:
                task.fn(due_ns)
            except BaseException:  # as before: a task that raised is not scheduled again
                pop(heap) if heap[0] is entry else self._drop(entry)
                raise
            task.k = k = task.k + 1
            if task.enabled:
                self._seq += 1
                per = task.period_ns  # Task.due inlined for whole-ns periods (the 500 Hz pair)
                nxt = (task.start_ns + k * per if per and k < _K_EXACT else task.due(k), order, self._seq, task)
                if heap[0] is entry:
                    replace(heap, nxt)
                else:  # the task pushed an entry before its own: take its own out, then push
                    self._drop(entry)
                    heapq.heappush(heap, nxt)
            elif heap[0] is entry:
                pop(heap)
            else:
                self._drop(entry)

    def _drop(self, entry) -> None:
        """Take ``entry`` out of the heap wherever it is (a task's own entry after it scheduled
        an earlier one while it ran)."""
        heap = self._heap
        i = next(j for j, e in enumerate(heap) if e is entry)
        heap[i] = heap[-1]
        heap.pop()
        if i < len(heap):
            heapq.heapify(heap)

    def run_for(self, seconds: float) -> None:
        """Advance virtual time by ``seconds`` [s]."""
        self.run_until(self.t_ns + int(round(seconds * 1e9)))

    def run_ticks(self, n: int) -> None:
        """Advance until ``n`` more heartbeat ticks have happened."""
        target = self.tick + n
        hb = self.tasks["heartbeat"]
        self.run_until(hb.due(hb.k + (target - self.tick) - 1))

    @property
    def t_s(self) -> float:
        return self.t_ns / 1e9
