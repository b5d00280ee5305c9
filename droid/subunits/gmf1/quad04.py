"""Driver of the CIO-QUAD04-like encoder cards (thesis §2.4, §4.2.5), chosen by URL.

URL forms (pyserial style: the scheme picks the backend, bad options are
refused with the expected form)::

    shm://NAME                  a POSIX shared-memory object /NAME holding the
                                register map (droid-sim's twin of the card)
    mem://PATH?offset=N         MAP_SIZE bytes at byte ``offset`` (decimal or 0x
                                hex) of a file or memory device, e.g. a UIO
                                window of a real adapter; tests use a temp file

The register layout is :mod:`droid.subunits.gmf1.quad04_map`.  Nothing here
knows whether the card is simulated.

* :class:`Quad04Card` — one card over a writable buffer: read the four
  counters and command counts in one access, write LATCH/RESET commands;
* :class:`Quad04Bank` — the two cards of the GMF1 as six joints
  (joint i = card i // 4, channel i % 4);
* :func:`open_card` / :func:`open_bank` — open by URL.

Errors: a malformed URL or a block that is not a card -> :class:`BadInput`
(exit 2); a card that is not there (yet) -> :class:`CardUnavailable`, a runtime
failure the encoder program retries.
"""
from __future__ import annotations

import mmap
import os
import re
from urllib.parse import parse_qs, urlsplit

import numpy as np
import posix_ipc

from droid.cli import BadInput, RuntimeFailure
from droid.subunits.gmf1 import quad04_map as qm

URL_FORMS = "shm://NAME or mem://PATH?offset=N"
_SHM_NAME = re.compile(r"^[A-Za-z0-9._-]{1,200}$")


class CardUnavailable(RuntimeFailure):
    """The card's memory is not there (object missing, file unreadable): retry later."""


class Quad04Card:
    """One 4-channel card over a writable buffer of at least MAP_SIZE bytes."""

    def __init__(self, buf, name: str = "card", *, check: bool = True, closer=None,
                 identity=None, opened_as=None) -> None:
        mv = memoryview(buf)
        if mv.nbytes < qm.MAP_SIZE:
            n = mv.nbytes
            mv.release()
            raise BadInput(f"{name}: {n} bytes is too small for an encoder card ({qm.MAP_SIZE})")
        self._mv = mv[: qm.MAP_SIZE]
        mv.release()
        self.name = name
        self._closer = closer
        # identity: () -> what object the path names now; opened_as: what we mapped
        self._identity = identity
        self.identity = opened_as
        if check:
            self.check_header()

    def check_header(self) -> None:
        magic, version, channels, _status = qm.HEADER.unpack_from(self._mv, 0)
        if magic != qm.MAGIC:
            raise BadInput(f"{self.name}: not an encoder card (magic 0x{magic:08x}, expected 0x{qm.MAGIC:08x})")
        if version != qm.VERSION or channels != qm.CHANNELS:
            raise BadInput(f"{self.name}: card map version {version} with {channels} channels, "
                           f"this driver speaks version {qm.VERSION} with {qm.CHANNELS}")

    @property
    def powered(self) -> bool:
        return bool(qm.U32.unpack_from(self._mv, qm.OFF_STATUS)[0] & qm.STATUS_POWER)

    def read(self) -> tuple[list[int], list[int]]:
        """(COUNT[4] [counts, 24-bit], DONE[4]) in one access."""
        w = qm.CHANNEL_BLOCK.unpack_from(self._mv, qm.OFF_CHANNEL0)
        return [w[0] & qm.COUNTER_MASK, w[4] & qm.COUNTER_MASK, w[8] & qm.COUNTER_MASK,
                w[12] & qm.COUNTER_MASK], [w[3], w[7], w[11], w[15]]

    def read_latch(self, ch: int) -> int:
        """LATCH register of channel ``ch`` [counts, 24-bit]."""
        return qm.U32.unpack_from(self._mv, qm.channel_offset(ch, qm.REG_LATCH))[0] & qm.COUNTER_MASK

    def command(self, ch: int, cmd: int) -> None:
        """Write a command (CMD_LATCH / CMD_RESET) into channel ``ch``'s CTRL register."""
        if cmd not in (qm.CMD_LATCH, qm.CMD_RESET):
            raise ValueError(f"unknown card command {cmd}")
        qm.U32.pack_into(self._mv, qm.channel_offset(ch, qm.REG_CTRL), cmd)

    def replaced(self) -> bool:
        """True if the object behind the map was removed or replaced since it was opened."""
        if self._identity is None:
            return False
        try:
            return self._identity() != self.identity
        except OSError:
            return True

    def close(self) -> None:
        if self._mv is not None:
            self._mv.release()
            self._mv = None
        if self._closer is not None:
            self._closer()
            self._closer = None


class Quad04Bank:
    """The GMF1's two cards as six joint encoders (joint i = card i // 4, channel i % 4)."""

    def __init__(self, cards: list[Quad04Card]) -> None:
        if len(cards) != qm.CARDS:
            raise BadInput(f"the GMF1 needs {qm.CARDS} encoder cards, got {len(cards)}")
        self.cards = cards

    def read_joints(self) -> tuple[np.ndarray, np.ndarray]:
        """(raw counters [counts, 24-bit], commands done) of the six joints, int64 arrays."""
        c0, d0 = self.cards[0].read()
        c1, d1 = self.cards[1].read()
        return np.array(c0 + c1[:2], np.int64), np.array(d0 + d1[:2], np.int64)

    def command_joints(self, cmd: int) -> None:
        """Write ``cmd`` into the CTRL register of every joint's channel."""
        for j in range(qm.JOINTS):
            card, ch = qm.joint_channel(j)
            self.cards[card].command(ch, cmd)

    def reset_joints(self) -> None:
        """Ask every joint counter to reset to 0 (done once DONE has advanced)."""
        self.command_joints(qm.CMD_RESET)

    @property
    def powered(self) -> bool:
        return all(c.powered for c in self.cards)

    def replaced(self) -> bool:
        return any(c.replaced() for c in self.cards)

    def close(self) -> None:
        for c in self.cards:
            c.close()


# -- opening by URL ---------------------------------------------------------------------
def open_card(url: str) -> Quad04Card:
    """Open one card by URL (see the module docstring)."""
    if not isinstance(url, str):
        raise BadInput(f"encoder card URL must be a string ({URL_FORMS})")
    if url.startswith("shm://"):
        return _open_shm(url)
    if url.startswith("mem://"):
        return _open_mem(url)
    raise BadInput(f"encoder card URL {url!r}: unknown scheme (expected {URL_FORMS})")


def open_bank(urls: list[str]) -> Quad04Bank:
    """Open the two cards of the GMF1 (closes what it opened if one fails)."""
    if not isinstance(urls, (list, tuple)) or len(urls) != qm.CARDS:
        raise BadInput(f"the GMF1 needs {qm.CARDS} encoder card URLs ({URL_FORMS})")
    cards: list[Quad04Card] = []
    try:
        for u in urls:
            cards.append(open_card(u))
    except BaseException:
        for c in cards:
            c.close()
        raise
    return Quad04Bank(cards)


def check_url(url: str) -> str:
    """Validate a card URL's form without opening it; returns it (BadInput if malformed)."""
    if isinstance(url, str) and url.startswith("shm://"):
        _shm_name(url)
        return url
    if isinstance(url, str) and url.startswith("mem://"):
        _mem_parts(url)
        return url
    raise BadInput(f"encoder card URL {url!r}: expected {URL_FORMS}")


def _shm_name(url: str) -> str:
    name = url[len("shm://"):]
    if not _SHM_NAME.match(name):
        raise BadInput(f"encoder card URL {url!r}: bad shared-memory name (letters, digits, '.', '_', '-'; "
                       f"expected shm://NAME)")
    return name


def _open_shm(url: str) -> Quad04Card:
    name = _shm_name(url)
    try:
        shm = posix_ipc.SharedMemory("/" + name)
    except posix_ipc.ExistentialError:
        raise CardUnavailable(f"encoder card {url}: no such shared-memory object (is droid-sim up?)") from None
    except posix_ipc.PermissionsError as exc:
        raise CardUnavailable(f"encoder card {url}: {exc}") from None
    try:
        if shm.size < qm.MAP_SIZE:
            raise BadInput(f"encoder card {url}: object is {shm.size} bytes, a card map is {qm.MAP_SIZE}")
        region = mmap.mmap(shm.fd, qm.MAP_SIZE)
        inode = os.fstat(shm.fd).st_ino
    finally:
        shm.close_fd()
    path = f"/dev/shm/{name}"

    def identity():
        return os.stat(path).st_ino

    try:
        return Quad04Card(region, url, closer=region.close, identity=identity, opened_as=inode)
    except BaseException:
        region.close()
        raise


def _mem_parts(url: str) -> tuple[str, int]:
    parts = urlsplit(url)
    path = parts.netloc + parts.path
    if not path:
        raise BadInput(f"encoder card URL {url!r}: no path (expected mem://PATH?offset=N)")
    try:
        query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise BadInput(f"encoder card URL {url!r}: bad query (expected mem://PATH?offset=N)") from None
    unknown = set(query) - {"offset"}
    if unknown:
        raise BadInput(f"encoder card URL {url!r}: unknown option(s) {', '.join(sorted(unknown))} "
                       f"(expected mem://PATH?offset=N)")
    offset = 0
    if "offset" in query:
        vals = query["offset"]
        try:
            if len(vals) != 1:
                raise ValueError
            offset = int(vals[0], 0)
        except ValueError:
            raise BadInput(f"encoder card URL {url!r}: offset must be one integer "
                           f"(decimal or 0x hex)") from None
        if offset < 0:
            raise BadInput(f"encoder card URL {url!r}: offset must be >= 0")
    return path, offset


def _open_mem(url: str) -> Quad04Card:
    path, offset = _mem_parts(url)
    try:
        fd = os.open(path, os.O_RDWR | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise CardUnavailable(f"encoder card {url}: {path} does not exist") from None
    except OSError as exc:
        raise CardUnavailable(f"encoder card {url}: cannot open {path} ({exc.strerror})") from None
    try:
        st = os.fstat(fd)
        if st.st_size and st.st_size < offset + qm.MAP_SIZE:
            raise BadInput(f"encoder card {url}: {path} is {st.st_size} bytes, too short for a card "
                           f"at offset {offset}")
        gran = mmap.ALLOCATIONGRANULARITY
        base = offset - offset % gran
        delta = offset - base
        try:
            region = mmap.mmap(fd, delta + qm.MAP_SIZE, offset=base)
        except (OSError, ValueError) as exc:
            raise CardUnavailable(f"encoder card {url}: cannot map {path} ({exc})") from None
        inode = (st.st_dev, st.st_ino)
    finally:
        os.close(fd)

    def identity():
        s = os.stat(path)
        return (s.st_dev, s.st_ino)

    view = memoryview(region)[delta: delta + qm.MAP_SIZE]

    def closer():
        view.release()
        region.close()

    try:
        return Quad04Card(view, url, closer=closer, identity=identity, opened_as=inode)
    except BaseException:
        closer()
        raise
