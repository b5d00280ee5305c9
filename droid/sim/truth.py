"""The world's ground truth, through its own door (issue 13: "the world is not the model").

The controller sees an arm only through its encoders; the world knows where
the arm really is (its link angles after the drives' deflection, with the true
switch positions and link lengths).  Tests and users who ask get that truth:

* in lockstep, from the twin itself (``LockstepArm.truth()``);
* from a running ``droid-sim``, through a small POSIX shared-memory record per
  arm, ``/droid.<cell>.<arm>.truth`` (:class:`TruthDoor`), which the world
  rewrites every 4 ms of world time (:data:`TRUTH_PERIOD_S`; the ABB's EGM twin too, where
  ``wcp_mm`` is its model's pose frame, the flange);
  ``droid-sim truth ARM --json [--cell FILE]`` prints it as one JSON object
  ``{"arm", "t_s", "q_deg": [6], "wcp_mm": [3]}`` (``q_deg``: the true joint
  angles [deg]; ``wcp_mm``: the true wrist-centre position in the global frame [mm]).

The record is written under a sequence lock (odd while writing), so a reader
never mixes two steps.  No DROID program reads it: it is the simulator's
window, not a sensor.
"""
from __future__ import annotations

import mmap
import struct
import time

import posix_ipc

#: The truth door is rewritten at most this often, in world time [s] (250 Hz: each record carries
#: its world time ``t_s``; a per-millisecond rewrite cost the world a forward kinematics a step).
TRUTH_PERIOD_S = 0.004
RECORD = struct.Struct("<Q d 6d 3d")  # seq, t_s, q_deg, wcp_mm
_SEQ = struct.Struct("<Q")  # the record's sequence word: odd while written, 0 before the first
SIZE = RECORD.size


def door_name(cell_name: str, arm: str) -> str:
    return f"droid.{cell_name}.{arm}.truth"


def truth_dict(arm: str, t_s: float, q_deg, wcp_mm) -> dict:
    return {"arm": arm, "t_s": round(float(t_s), 6), "q_deg": [float(x) for x in q_deg],
            "wcp_mm": [float(x) for x in wcp_mm]}


class TruthDoor:
    """One arm's truth record in shared memory (the world writes, anyone reads)."""

    def __init__(self, name: str, shm, region: mmap.mmap, owner: bool) -> None:
        self.name, self._shm, self._region, self._owner = name, shm, region, owner
        self._seq = 0

    @classmethod
    def create(cls, name: str) -> "TruthDoor":
        try:
            posix_ipc.unlink_shared_memory("/" + name)
        except posix_ipc.ExistentialError:
            pass
        shm = posix_ipc.SharedMemory("/" + name, posix_ipc.O_CREX, mode=0o600, size=SIZE)
        region = mmap.mmap(shm.fd, SIZE)
        shm.close_fd()
        return cls(name, shm, region, True)

    @classmethod
    def open(cls, name: str) -> "TruthDoor":
        """Open an existing record; raises ``posix_ipc.ExistentialError`` if the world is not up."""
        shm = posix_ipc.SharedMemory("/" + name)
        region = mmap.mmap(shm.fd, SIZE, prot=mmap.PROT_READ)
        shm.close_fd()
        return cls(name, shm, region, False)

    def write(self, t_s: float, q_deg, wcp_mm) -> None:
        # slice assignments (one copy each), never pack_into, which zero-fills first: a reader
        # would see a sequence of 0, "nothing written yet" (docs/architecture.md)
        self._seq += 1
        odd = 2 * self._seq - 1
        self._region[0:8] = _SEQ.pack(odd)  # odd: being written
        self._region[0:RECORD.size] = RECORD.pack(odd, t_s, *q_deg, *wcp_mm)
        self._region[0:8] = _SEQ.pack(2 * self._seq)

    def read(self, timeout_s: float = 1.0) -> tuple[float, list, list] | None:
        """(t_s, q_deg, wcp_mm) of one consistent step, or None if nothing was written yet."""
        deadline = time.monotonic() + timeout_s
        while True:
            v = RECORD.unpack_from(self._region, 0)
            seq2 = _SEQ.unpack_from(self._region, 0)[0]
            if v[0] == seq2 and v[0] % 2 == 0:
                if v[0] == 0:
                    return None
                return v[1], list(v[2:8]), list(v[8:11])
            if time.monotonic() > deadline:
                return None
            time.sleep(0.0001)

    def close(self) -> None:
        self._region.close()
        if self._owner:
            try:
                posix_ipc.unlink_shared_memory("/" + self.name)
            except posix_ipc.ExistentialError:
                pass
