"""Driver of the CIO-QUAD04-like encoder cards (thesis §2.4, §4.2.5), chosen by URL.

URL forms (pyserial style: the scheme picks the backend, bad options are
refused with the expected form)::

    shm://NAME                  a POSIX shared-memory object /NAME holding the
                                register map (droid-sim's twin of the card)
    mem:///PATH?offset=N        MAP_SIZE bytes at byte ``offset`` (decimal or 0x
                                hex) of a file or memory device, e.g. a UIO
                                window of a real adapter; tests use a temp file

Both are opened by :mod:`droid.subunits.regmap` (the same handlers as the VME driver).

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

import numpy as np

from droid.brain.cell.registry import open_url
from droid.cli import BadInput
from droid.subunits.gmf1 import quad04_map as qm
from droid.subunits.regmap import URL_FORMS, MapUnavailable, identity_changed, open_region, parse_url

#: the card's memory is not there (object missing, file unreadable): retry later
#: (the register-map error every driver shares, droid.subunits.regmap)
CardUnavailable = MapUnavailable


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
        self._words = qm.words(self._mv)  # CTRL writes as single stores (qm.words)
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

    def channel_bytes(self) -> bytes:
        """The four channels' registers (COUNT, LATCH, CTRL, DONE each) as bytes: what :meth:`read`
        reads, and more (an unchanged block reads the same)."""
        return bytes(self._mv[qm.OFF_CHANNEL0:qm.OFF_CHANNEL0 + qm.CHANNEL_BLOCK.size])

    def read_latch(self, ch: int) -> int:
        """LATCH register of channel ``ch`` [counts, 24-bit]."""
        return qm.U32.unpack_from(self._mv, qm.channel_offset(ch, qm.REG_LATCH))[0] & qm.COUNTER_MASK

    def command(self, ch: int, cmd: int) -> None:
        """Write a command (CMD_LATCH / CMD_RESET) into channel ``ch``'s CTRL register."""
        if cmd not in (qm.CMD_LATCH, qm.CMD_RESET):
            raise ValueError(f"unknown card command {cmd}")
        self._words[qm.channel_offset(ch, qm.REG_CTRL) // 4] = cmd

    def replaced(self) -> bool:
        """True if the object behind the map was removed or replaced since it was opened."""
        return identity_changed(self._identity, self.identity)

    def close(self) -> None:
        if self._mv is not None:
            self._words.release()
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

    def channel_bytes(self) -> bytes | None:
        """Both cards' channel registers as bytes (Quad04Card.channel_bytes; :meth:`joints_from`
        reads them as :meth:`read_joints` reads the cards), or None when a card is not a plain
        :class:`Quad04Card` (a driver of its own reads through its own ``read``)."""
        c0, c1 = self.cards
        if type(c0) is not Quad04Card or type(c1) is not Quad04Card:
            return None
        return c0.channel_bytes() + c1.channel_bytes()

    @staticmethod
    def joints_from(regs: bytes) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`read_joints` of the registers :meth:`channel_bytes` returned."""
        m, n = qm.COUNTER_MASK, qm.CHANNEL_BLOCK.size
        w = qm.CHANNEL_BLOCK.unpack_from(regs, 0)
        x = qm.CHANNEL_BLOCK.unpack_from(regs, n)
        return (np.array([w[0] & m, w[4] & m, w[8] & m, w[12] & m, x[0] & m, x[4] & m], np.int64),
                np.array([w[3], w[7], w[11], w[15], x[3], x[7]], np.int64))

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


# -- opening by URL (droid.subunits.regmap: one table of shm:// / mem:// handlers) -------------
def open_card(url: str) -> Quad04Card:
    """Open one card by URL (see the module docstring)."""
    region = open_region(url, qm.MAP_SIZE, "encoder card", hint="is droid-sim up?")
    try:
        return Quad04Card(region.buf, url, closer=region.close, identity=region.identity,
                          opened_as=region.opened_as)
    except BaseException:
        region.close()
        raise


def open_bank(urls: list[str]) -> Quad04Bank:
    """Open the two cards of the GMF1 (closes what it opened if one fails)."""
    if not isinstance(urls, (list, tuple)) or len(urls) != qm.CARDS:
        raise BadInput(f"the GMF1 needs {qm.CARDS} encoder card URLs ({URL_FORMS})")
    cards: list[Quad04Card] = []
    try:
        for u in urls:
            cards.append(open_url(u, "encoder_card"))  # open_card, through the registry
    except BaseException:
        for c in cards:
            c.close()
        raise
    return Quad04Bank(cards)


def check_url(url: str) -> str:
    """Validate a card URL's form without opening it; returns it (BadInput if malformed)."""
    parse_url(url, "encoder card")
    return url
