"""The simulated Reis register map as a POSIX shared-memory object.

droid-sim creates ``/NAME`` (MAP_SIZE bytes, :mod:`droid.subunits.reis.vme_map`)
and runs a :class:`droid.sim.reis.plant.ReisPlant` on it; droid-servo and
droid-watchdog open the same bytes with ``open_vme("shm://NAME")``::

    with SharedVmeMap.create("droid.mycell.arm1.vme") as shared:
        plant = ReisPlant(params, seed, regs=shared.buf)
        ...
        plant.close()           # release the plant's view before the map closes
"""
from __future__ import annotations

import mmap
import re

import posix_ipc

from droid.subunits.reis import vme_map as vm

_NAME = re.compile(r"^[A-Za-z0-9._-]{1,200}$")


class SharedVmeMap:
    """Owner of the shared-memory register map: creates it, unlinks it on close."""

    def __init__(self, name: str, shm: posix_ipc.SharedMemory, region: mmap.mmap):
        self.name = name
        self._shm = shm
        self.buf = region  # writable, MAP_SIZE bytes

    @property
    def url(self) -> str:
        """The driver URL of this map (``shm://NAME``)."""
        return f"shm://{self.name}"

    @classmethod
    def create(cls, name: str, replace: bool = False) -> "SharedVmeMap":
        """Create ``/name`` zero-filled.  ``replace``: unlink a stale object first."""
        if not _NAME.match(name):
            raise ValueError(f"bad shared-memory name {name!r} (letters, digits, '.', '_', '-')")
        if replace:
            try:
                posix_ipc.unlink_shared_memory("/" + name)
            except posix_ipc.ExistentialError:
                pass
        shm = posix_ipc.SharedMemory("/" + name, posix_ipc.O_CREX, mode=0o600, size=vm.MAP_SIZE)
        try:
            region = mmap.mmap(shm.fd, vm.MAP_SIZE)
        except Exception:
            shm.close_fd()
            shm.unlink()
            raise
        shm.close_fd()
        return cls(name, shm, region)

    def close(self, unlink: bool = True) -> None:
        """Unmap (all views on ``buf`` must be released first) and unlink."""
        if self.buf is not None:
            self.buf.close()
            self.buf = None
        if unlink:
            try:
                posix_ipc.unlink_shared_memory("/" + self.name)
            except posix_ipc.ExistentialError:
                pass

    def __enter__(self) -> "SharedVmeMap":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
