"""The ABB subunit's keys in the cell file ([subunits.NAME]; docs/abb.md).

    egm = "udp://127.0.0.1:6510"   # where droid-egm binds its UDP socket: the address the robot
                                   # controller's EGM transmission configuration names (the
                                   # "remote address"/"remote port number" of its UDPUC device)

With an ``[interpose]`` entry ``"udp://H:P" = "udp://H:P2"`` droid-egm binds ``udp://H:P2`` and a
fault proxy serves ``udp://H:P`` (droid-fault, docs/safety.md); the controller still sends to P.

The EGM link's UDP plumbing is the Brain's (droid.brain.plumbing.udp), once for every end of the
link: droid-egm, the controller twin in droid-sim and droid-fault's proxy parse ``udp://HOST:PORT``
with :func:`udp_address` and open their sockets with :func:`bind_udp` (both named here too).
:func:`proxy_endpoints` tells droid-fault's proxy the EGM address to interpose (the package's
``DevicePackage.proxy_endpoints``).
"""
from __future__ import annotations

from dataclasses import dataclass

from droid.brain.cell.cellfile import Cell, Subunit
from droid.brain.plumbing.udp import bind_udp, udp_address  # noqa: F401 (named here for droid-egm and its twin)
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
        return EgmConfig(*udp_address(url))
    except BadInput as exc:
        raise BadInput(f"{where} egm {exc}") from None


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


def proxy_endpoints(cell: Cell, sub: Subunit) -> list[tuple[str, str, str]]:
    """The endpoints of ``sub`` a fault proxy may interpose beyond the cell's ZeroMQ ones
    (``DevicePackage.proxy_endpoints``; droid.faults.proxy.cell_endpoints): an ABB subunit's EGM
    address, ``egm``, of kind ``udp`` -- where it runs droid-egm or names an ``egm`` address; none
    otherwise.  A malformed address is BadInput (droid-fault list / interpose / proxy refuse it)."""
    if "droid-egm" not in sub.programs and "egm" not in sub.options:
        return []
    egm_config(cell, sub)
    return [("egm", egm_url(sub), "udp")]
