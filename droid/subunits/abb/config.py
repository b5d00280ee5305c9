"""The ABB subunit's keys in the cell file ([subunits.NAME]; docs/abb.md).

    egm = "udp://127.0.0.1:6510"   # where droid-egm binds its UDP socket: the address the robot
                                   # controller's EGM transmission configuration names (the
                                   # "remote address"/"remote port number" of its UDPUC device)
"""
from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import urlsplit

from droid.brain.cellfile import Cell, Subunit
from droid.cli import BadInput

DEFAULT_EGM_PORT = 6510  # the port of ABB's EGM examples (and abb-robot-client's default)


@dataclass(frozen=True)
class EgmConfig:
    host: str  # the sensor's (this PC's) address
    port: int  # its UDP port

    @property
    def address(self) -> tuple[str, int]:
        return (self.host, self.port)


def parse_egm_url(url, where: str) -> EgmConfig:
    """``udp://HOST:PORT`` -> EgmConfig; anything else is BadInput naming ``where``."""
    if not isinstance(url, str):
        raise BadInput(f"{where} egm must be a string udp://HOST:PORT")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError:
        raise BadInput(f"{where} egm {url!r}: not udp://HOST:PORT (port 1..65535)") from None
    if parts.scheme != "udp" or not parts.hostname or port is None or not 1 <= port <= 65535 \
            or parts.path not in ("", "/") or parts.query or parts.fragment:
        raise BadInput(f"{where} egm {url!r}: not udp://HOST:PORT (port 1..65535)")
    return EgmConfig(parts.hostname, port)


def egm_config(cell: Cell, sub: Subunit) -> EgmConfig:
    url = sub.options.get("egm", f"udp://127.0.0.1:{DEFAULT_EGM_PORT}")
    return parse_egm_url(url, f"{cell.path}: [subunits.{sub.name}]")
