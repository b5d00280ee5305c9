"""The ABB subunit's keys in the cell file ([subunits.NAME]; docs/abb.md).

    egm = "udp://127.0.0.1:6510"   # where droid-egm binds its UDP socket: the address the robot
                                   # controller's EGM transmission configuration names (the
                                   # "remote address"/"remote port number" of its UDPUC device)

With an ``[interpose]`` entry ``"udp://H:P" = "udp://H:P2"`` droid-egm binds ``udp://H:P2`` and a
fault proxy serves ``udp://H:P`` (droid-fault, docs/safety.md); the controller still sends to P.

The EGM link's UDP plumbing is here too, once for every end of the link: droid-egm, the
controller twin in droid-sim and droid-fault's proxy parse ``udp://HOST:PORT`` with
:func:`udp_address` and open their sockets with :func:`bind_udp`.
"""
from __future__ import annotations

import errno
import socket
from dataclasses import dataclass
from urllib.parse import urlsplit

from droid.brain.cell.cellfile import Cell, Subunit
from droid.cli import BadInput, RuntimeFailure

DEFAULT_EGM_PORT = 6510  # the port of ABB's EGM examples (and abb-robot-client's default)


@dataclass(frozen=True)
class EgmConfig:
    host: str  # the sensor's (this PC's) address
    port: int  # its UDP port

    @property
    def address(self) -> tuple[str, int]:
        return (self.host, self.port)


def udp_address(url) -> tuple[str, int]:
    """``udp://HOST:PORT`` -> (host, port); anything else is BadInput (one line naming it)."""
    if not isinstance(url, str):
        raise BadInput(f"{url!r}: not a string udp://HOST:PORT")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError:
        raise BadInput(f"{url!r}: not udp://HOST:PORT (port 1..65535)") from None
    if parts.scheme != "udp" or not parts.hostname or port is None or not 1 <= port <= 65535 \
            or parts.path not in ("", "/") or parts.query or parts.fragment:
        raise BadInput(f"{url!r}: not udp://HOST:PORT (port 1..65535)")
    return parts.hostname, port


def parse_egm_url(url, where: str) -> EgmConfig:
    """``udp://HOST:PORT`` -> EgmConfig; anything else is BadInput naming ``where``."""
    if not isinstance(url, str):
        raise BadInput(f"{where} egm must be a string udp://HOST:PORT")
    try:
        return EgmConfig(*udp_address(url))
    except BadInput as exc:
        raise BadInput(f"{where} egm {exc}") from None


def bind_udp(address: tuple[str, int] | None, who: str = "", buffer_bytes: int | None = None) -> socket.socket:
    """A non-blocking IPv4 UDP socket bound to ``address`` (None: left unbound, the kernel picks a
    port at the first send); ``buffer_bytes``: its kernel receive and send buffers asked for.  A
    socket that cannot be bound is RuntimeFailure (exit 1), one line: ``WHO: cannot bind UDP
    HOST:PORT: in use``."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        if buffer_bytes is not None:
            for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
                sock.setsockopt(socket.SOL_SOCKET, opt, buffer_bytes)
        if address is not None:
            sock.bind(address)
    except OSError as exc:
        sock.close()
        why = "in use" if exc.errno == errno.EADDRINUSE else (exc.strerror or str(exc))
        where = "a UDP socket" if address is None else f"UDP {address[0]}:{address[1]}"
        raise RuntimeFailure(f"{who + ': ' if who else ''}cannot bind {where}: {why}") from None
    sock.setblocking(False)
    return sock


def egm_url(sub: Subunit):
    """The subunit's ``egm`` value as the cell file gives it (unchecked), or the default."""
    return sub.options.get("egm", f"udp://127.0.0.1:{DEFAULT_EGM_PORT}")


def egm_config(cell: Cell, sub: Subunit) -> EgmConfig:
    """The public address: where the robot controller (and its twin) sends ``EgmRobot``."""
    return parse_egm_url(egm_url(sub), f"{cell.path}: [subunits.{sub.name}]")


def egm_bind_config(cell: Cell, sub: Subunit) -> EgmConfig:
    """Where droid-egm binds: the public address, or its ``[interpose]`` inner address when a
    fault proxy (``droid-fault proxy SUB.egm``, docs/safety.md) serves the public one."""
    public = egm_config(cell, sub)
    inner = cell.bind_endpoint(egm_url(sub))
    if inner == egm_url(sub):
        return public
    return parse_egm_url(inner, f"{cell.path}: [interpose] for [subunits.{sub.name}]")
