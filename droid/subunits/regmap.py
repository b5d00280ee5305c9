"""Register maps by URL: the one opener of ``shm://`` and ``mem://`` for every driver.

The Reis VME cards (:mod:`droid.subunits.reis.vme`), the GMF1's encoder
cards (:mod:`droid.subunits.gmf1.quad04`) and the MVS DSP board
(:mod:`droid.subunits.mvs.dsp`) are all a block of registers in memory.  As
pyserial chooses a port by URL through a table of handlers, a driver here
asks :func:`open_region` for ``size`` bytes at a URL and gets a
:class:`Region`; :data:`HANDLERS` maps the scheme to its opener:

``shm://NAME``
    the POSIX shared-memory object ``/NAME`` (droid-sim's twin of the card);
    NAME is 1-200 of ``A-Z a-z 0-9 . _ -``; no path, no options.
``mem:///PATH?offset=0xADDR``
    ``size`` bytes of a device or regular file (``/dev/mem``, ``/dev/uioN``)
    at byte ADDR (decimal or 0x hex, default 0): the real-hardware path.
    PATH is absolute.

One set of errors for every driver: a malformed URL is :class:`MapUrlError`
(a :class:`~droid.cli.BadInput`: exit 2, the expected forms in the message);
a well-formed URL whose memory is not there (yet) -- no such object, a file
that cannot be opened or is too short -- is :class:`MapUnavailable` (a
:class:`~droid.cli.RuntimeFailure`: exit 1, or retry later).

A :class:`Region` remembers the identity (inode) of what it mapped, so a
driver notices when droid-sim was restarted and the name now holds a new
object (:meth:`Region.replaced`).
"""
from __future__ import annotations

import mmap
import os
import re
from typing import Callable
from urllib.parse import parse_qsl, urlsplit

from droid.cli import BadInput, RuntimeFailure

SHM_FORM = "shm://NAME (NAME: letters, digits, '.', '_', '-')"
MEM_FORM = "mem:///PATH?offset=0xADDR (PATH absolute, e.g. mem:///dev/uio0?offset=0x0)"
URL_FORMS = f"{SHM_FORM} or {MEM_FORM}"
SHM_NAME = re.compile(r"^[A-Za-z0-9._-]{1,200}$")


class MapUrlError(BadInput, ValueError):
    """A malformed or unsupported register-map URL (exit code 2 in a shell)."""


class MapUnavailable(RuntimeFailure, OSError):
    """The URL is well formed but its memory is not there (yet): exit code 1, or retry."""


class Region:
    """``size`` bytes of a register map: a writable memoryview, and how to release it."""

    def __init__(self, buf, url: str, closer: Callable[[], None] | None = None,
                 identity: Callable[[], object] | None = None, opened_as: object = None) -> None:
        self.buf = buf
        self.url = url
        self._closer = closer
        self.identity = identity  # () -> what the name holds now (None: cannot tell)
        self.opened_as = opened_as  # what was mapped

    def replaced(self) -> bool:
        """True if the name now holds another object than the one mapped (or nothing)."""
        return identity_changed(self.identity, self.opened_as)

    def close(self) -> None:
        if self._closer is not None:
            closer, self._closer = self._closer, None
            closer()


def identity_changed(identity: Callable[[], object] | None, opened_as: object) -> bool:
    """True if ``identity()`` (what a name holds now) differs from ``opened_as``, or the name is gone."""
    if identity is None:
        return False
    try:
        return identity() != opened_as
    except OSError:
        return True


def parse_url(url, what: str, schemes: tuple[str, ...] = ("shm", "mem"), forms: str = URL_FORMS):
    """Check a URL's form; returns ``(scheme, name_or_path, offset)``.

    ``what`` names the device in messages ("VME", "encoder card", "DSP");
    ``schemes`` are the ones this driver takes (``shm``, ``mem`` and, for
    in-process channels, ``inproc`` -- NAME like shm)."""
    def bad(problem: str) -> MapUrlError:
        return MapUrlError(f"{what} URL {url!r}: {problem}; expected {forms}")

    if not isinstance(url, str):
        raise bad("not a string")
    parts = urlsplit(url)
    if parts.scheme not in schemes or "://" not in url:
        raise bad("unknown scheme")
    if parts.scheme in ("shm", "inproc"):
        if parts.query or parts.fragment:
            raise bad("takes no options")
        if parts.path or not SHM_NAME.match(parts.netloc):
            raise bad("NAME must be 1-200 of A-Z a-z 0-9 _ . -")
        return parts.scheme, parts.netloc, 0
    # mem
    if parts.netloc or not parts.path.startswith("/") or parts.fragment:
        raise bad("PATH must be absolute")
    offset = 0
    try:
        opts = parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise bad("bad options") from None
    seen = set()
    for key, value in opts:
        if key != "offset":
            raise bad(f"unknown option {key!r}")
        if key in seen:
            raise bad("offset given twice")
        seen.add(key)
        try:
            offset = int(value, 0)
        except ValueError:
            raise bad(f"offset {value!r} is not an integer") from None
        if offset < 0:
            raise bad("offset must be >= 0")
    return "mem", parts.path, offset


def _map_shm(url: str, name: str, _offset: int, size: int, hint: str) -> Region:
    import posix_ipc

    try:
        shm = posix_ipc.SharedMemory("/" + name)
    except posix_ipc.ExistentialError:
        raise MapUnavailable(f"{url}: no shared-memory object /{name} ({hint})") from None
    except posix_ipc.PermissionsError as exc:
        raise MapUnavailable(f"{url}: {exc}") from None
    try:
        if shm.size < size:
            raise MapUnavailable(f"{url}: /{name} has {shm.size} bytes, need {size}")
        region = mmap.mmap(shm.fd, size)
        inode = os.fstat(shm.fd).st_ino
    finally:
        shm.close_fd()
    path = f"/dev/shm/{name}"
    view = memoryview(region)
    return Region(view, url, closer=_releaser(view, region),
                  identity=lambda: os.stat(path).st_ino, opened_as=inode)


def _map_mem(url: str, path: str, offset: int, size: int, _hint: str) -> Region:
    try:
        fd = os.open(path, os.O_RDWR | os.O_SYNC | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise MapUnavailable(f"{url}: cannot open {path}: {exc.strerror}") from None
    try:
        st = os.fstat(fd)
        if os.path.isfile(path) and st.st_size < offset + size:
            raise MapUnavailable(f"{url}: {path} is shorter than offset + {size} bytes")
        base = offset - offset % mmap.ALLOCATIONGRANULARITY
        try:
            region = mmap.mmap(fd, offset - base + size, offset=base)
        except (OSError, ValueError) as exc:
            raise MapUnavailable(f"{url}: cannot map {path}: {exc}") from None
    finally:
        os.close(fd)
    window = memoryview(region)[offset - base: offset - base + size]

    def identity():
        s = os.stat(path)
        return (s.st_dev, s.st_ino)

    return Region(window, url, closer=_releaser(window, region), identity=identity,
                  opened_as=(st.st_dev, st.st_ino))


def _releaser(view, region) -> Callable[[], None]:
    def close() -> None:
        view.release()
        region.close()
    return close


#: scheme -> opener(url, name_or_path, offset, size, hint) (the handler table)
HANDLERS: dict[str, Callable[..., Region]] = {"shm": _map_shm, "mem": _map_mem}


def open_region(url, size: int, what: str, *, forms: str = URL_FORMS,
                hint: str = "is droid-sim running?") -> Region:
    """Map ``size`` bytes of the register map at ``url`` (see the module docstring)."""
    scheme, where, offset = parse_url(url, what, tuple(HANDLERS), forms)
    return HANDLERS[scheme](url, where, offset, size, hint)
