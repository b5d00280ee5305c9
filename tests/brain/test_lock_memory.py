"""droid.brain.runtime.rt.lock_memory locks what a program touches, not every mapping (issue 28).

Run in a child process, since locking is process-wide.  The child locks, then (a) starts a
thread -- an 8 MB stack it barely touches -- and (b) writes a fresh 16 MB buffer.  With the
old ``MCL_CURRENT | MCL_FUTURE`` the whole stack was locked as it was mapped; with
``MCL_ONFAULT`` only touched pages are, and the written buffer is locked page by page.
"""
from __future__ import annotations

import json
import subprocess
import sys

CHILD = r"""
import json, threading
from droid.brain.runtime.rt import lock_memory

def locked_kb():  # resident locked pages (VmLck would count whole locked mappings)
    for line in open("/proc/self/smaps_rollup"):
        if line.startswith("Locked:"):
            return int(line.split()[1])

ok = lock_memory("test")
before = locked_kb()
t = threading.Thread(target=lambda: None); t.start(); t.join()
after_thread = locked_kb()
buf = bytearray(16 * 1024 * 1024)
for i in range(0, len(buf), 4096):
    buf[i] = 1
after_buf = locked_kb()
print(json.dumps({"ok": ok, "before": before, "thread": after_thread, "buf": after_buf}))
"""


def test_lock_memory_locks_touched_pages_only():
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["ok"], "mlockall refused (this suite runs as root, as CI does)"
    assert got["before"] < 80 * 1024, got  # a program's start-up, not hundreds of MB
    assert got["thread"] - got["before"] < 2 * 1024, got  # an 8 MB thread stack is not populated
    assert got["buf"] - got["thread"] >= 8 * 1024, got  # pages touched later are locked (MCL_FUTURE)
