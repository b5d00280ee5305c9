"""The machine's latency floor, measured beside a benchmark's figures (docs/design.md §9).

``cyclictest`` (Debian package rt-tests) runs a SCHED_FIFO thread that sleeps
to absolute deadlines and records how late it woke: on a shared host its
figures say how noisy the machine was *during this run*, so a bench prints
them next to its own.  Without cyclictest (or without the privilege to use
SCHED_FIFO) the floor is reported as unavailable, never guessed.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import time

_LINE = re.compile(r"Min:\s*(\d+)\s+Act:\s*\d+\s+Avg:\s*(\d+)\s+Max:\s*(\d+)")


def when_and_load() -> str:
    """The line a bench prints before its figures: the date (UTC), the load average and the CPUs."""
    return (f"{time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}, load average "
            f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}, {os.cpu_count()} CPUs")


def cyclictest_floor(seconds: float = 2.0, interval_us: int = 1000, priority: int = 80) -> str:
    """One line: cyclictest wake-up latency min/avg/max [us] over ``seconds``, and the load average."""
    exe = shutil.which("cyclictest")
    load = "load average " + " ".join(f"{v:.2f}" for v in os.getloadavg())
    if exe is None:
        return f"floor: cyclictest not installed (apt-get install rt-tests); {load}"
    loops = max(1, int(seconds * 1e6 / interval_us))
    cmd = [exe, "-q", "-m", "-p", str(priority), "-i", str(interval_us), "-l", str(loops), "-t", "1"]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=seconds + 10).stdout
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"floor: cyclictest failed ({type(exc).__name__}); {load}"
    m = _LINE.search(out)
    if m is None:
        return f"floor: cyclictest gave no figures (needs root for SCHED_FIFO); {load}"
    lo, avg, hi = m.groups()
    return (
        f"floor: cyclictest SCHED_FIFO {priority}, {interval_us} us period, {loops} wake-ups: "
        f"latency min {lo} / avg {avg} / max {hi} us; {load}"
    )


if __name__ == "__main__":
    print(cyclictest_floor())
