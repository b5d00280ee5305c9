"""UDP plumbing: ``udp://HOST:PORT`` addresses and non-blocking sockets (docs/design.md §7).

Once for every end of a UDP link: an ABB arm's EGM link (droid-egm, the controller twin in
droid-sim, droid.subunits.abb.config) and droid-fault's proxy of it (droid.faults.proxy, kind
``udp``) parse addresses with :func:`udp_address` and open their sockets with :func:`bind_udp`.
"""
from __future__ import annotations

import errno
import socket
from urllib.parse import urlsplit

from droid.cli import BadInput, RuntimeFailure


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
