"""Fault decisions, pure and seeded (no I/O, no clock): the core of the fault injector.

:class:`LinkFaults` says how a link misbehaves; :class:`MessageFate` decides,
for each message, whether it is dropped, delayed and how often it is
delivered.  The same seed gives the same fates in the same order.
"""
from __future__ import annotations

import math
import random
from dataclasses import asdict, dataclass, fields, replace

from droid.cli import BadInput


#: The longest delay (and jitter) a faulty link adds to a message [ms]: one minute.
MAX_LINK_DELAY_MS = 60_000.0


@dataclass(frozen=True)
class LinkFaults:
    """How a link misbehaves, per message.

    ``drop`` and ``duplicate`` are probabilities (0..1); ``delay_ms`` is added
    to every delivered copy, plus a uniform 0..``jitter_ms`` [ms]; ``cut``
    drops everything in both directions (a host cut off)."""

    drop: float = 0.0
    duplicate: float = 0.0
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    cut: bool = False

    def __post_init__(self) -> None:
        for name in ("drop", "duplicate"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
                raise BadInput(f"{name} must be a probability between 0 and 1, got {v!r}")
        for name in ("delay_ms", "jitter_ms"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0.0 <= v <= MAX_LINK_DELAY_MS):
                raise BadInput(f"{name} must be between 0 and {MAX_LINK_DELAY_MS:g} ms, got {v!r}")

    @property
    def clean(self) -> bool:
        return self == LinkFaults()

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, base: "LinkFaults | None" = None) -> "LinkFaults":
        """``base`` updated by the keys of ``d`` (unknown keys are refused)."""
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise BadInput(f"unknown link fault(s) {', '.join(sorted(unknown))} (known: {', '.join(sorted(known))})")
        vals = {k: (bool(v) if k == "cut" else float(v)) for k, v in d.items()}
        return replace(base or cls(), **vals)


class MessageFate:
    """Per-message decisions for one link direction.  Pure and seeded."""

    def __init__(self, seed: int = 0) -> None:
        self._rng = random.Random(seed)
        self.passed = self.dropped = self.duplicated = self.delayed = 0

    def decide(self, faults: LinkFaults) -> list[int]:
        """The delays [ns] of the copies to deliver: [] drops the message, [0] passes it
        unchanged, two entries duplicate it.  Always draws the same number of random
        numbers, so the sequence of fates depends only on the seed and the message count."""
        r_drop, r_dup, r_jit, r_jit2 = (self._rng.random() for _ in range(4))
        if faults.cut or r_drop < faults.drop:
            self.dropped += 1
            return []
        base = faults.delay_ms + faults.jitter_ms * r_jit
        delays = [int(round(base * 1e6))]
        if r_dup < faults.duplicate:
            self.duplicated += 1
            delays.append(int(round((base + faults.jitter_ms * r_jit2) * 1e6)))
        if base > 0:
            self.delayed += 1
        self.passed += 1
        return delays

    def counts(self) -> dict:
        return {"passed": self.passed, "dropped": self.dropped, "duplicated": self.duplicated,
                "delayed": self.delayed}


class DelayLine:
    """Messages held until their release time [ns], released in time order (FIFO at equal times)."""

    def __init__(self) -> None:
        self._items: list[tuple[int, int, object]] = []
        self._n = 0

    def put(self, release_ns: int, item) -> None:
        import heapq

        heapq.heappush(self._items, (release_ns, self._n, item))
        self._n += 1

    def due(self, now_ns: int) -> list:
        import heapq

        out = []
        while self._items and self._items[0][0] <= now_ns:
            out.append(heapq.heappop(self._items)[2])
        return out

    def next_ns(self) -> int | None:
        return self._items[0][0] if self._items else None

    def __len__(self) -> int:
        return len(self._items)
