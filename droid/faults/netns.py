"""Two hosts on one machine: network namespaces joined by a veth pair (iproute2).

:class:`HostPair` creates two namespaces, ``droidf-<tag>-a`` and
``droidf-<tag>-b``, with loopback up and one veth pair between them
(10.213.<subnet>.1/24 in a, .2/24 in b), and removes them again.  Nothing
leaves the machine: the addresses exist only inside these namespaces.
"Cut a host off" is ``ip link set <veth> down`` on its side; restoring sets
it up again.  Every namespace this module makes starts with ``droidf-``, so a
test fixture can prove none is left behind (:func:`leftovers`).

Needs root (CAP_NET_ADMIN) and ``ip``.
"""
from __future__ import annotations

import shutil
import subprocess
import uuid
from dataclasses import dataclass

from droid.cli import RuntimeFailure

PREFIX = "droidf-"
VETH_PREFIX = "dfv"


def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    """Run ``ip ARGS``; RuntimeFailure with its message if it fails (and ``check``)."""
    out = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)
    if check and out.returncode != 0:
        raise RuntimeFailure(f"ip {' '.join(args)}: {out.stderr.strip() or out.returncode}")
    return out


def available() -> str | None:
    """None if namespaces can be made here, else the reason why not."""
    if shutil.which("ip") is None:
        return "iproute2 'ip' is not installed"
    probe = f"{PREFIX}probe-{uuid.uuid4().hex[:6]}"
    out = ip("netns", "add", probe, check=False)
    if out.returncode != 0:
        return f"cannot create a network namespace: {out.stderr.strip()}"
    ip("netns", "del", probe, check=False)
    return None


def leftovers() -> list[str]:
    """Namespaces and root-namespace links made by this module that still exist."""
    ns = ip("netns", "list", check=False).stdout.split("\n")
    names = [line.split()[0] for line in ns if line.startswith(PREFIX)]
    links = ip("-o", "link", "show", check=False).stdout.splitlines()
    names += [ln.split(":")[1].strip().split("@")[0] for ln in links
              if len(ln.split(":")) > 1 and ln.split(":")[1].strip().startswith(VETH_PREFIX)]
    return names


@dataclass
class HostPair:
    """Two namespaces a, b joined by a veth pair.  Use as a context manager."""

    subnet: int = 213
    tag: str = ""

    def __post_init__(self) -> None:
        self.tag = self.tag or uuid.uuid4().hex[:6]
        self.ns_a, self.ns_b = f"{PREFIX}{self.tag}-a", f"{PREFIX}{self.tag}-b"
        self.dev_a, self.dev_b = f"{VETH_PREFIX}{self.tag}a", f"{VETH_PREFIX}{self.tag}b"
        self.addr_a, self.addr_b = f"10.213.{self.subnet}.1", f"10.213.{self.subnet}.2"
        self._made: list[str] = []

    def create(self) -> "HostPair":
        try:
            for ns in (self.ns_a, self.ns_b):
                ip("netns", "add", ns)
                self._made.append(ns)
                ip("-n", ns, "link", "set", "lo", "up")
            ip("link", "add", self.dev_a, "type", "veth", "peer", "name", self.dev_b)
            ip("link", "set", self.dev_a, "netns", self.ns_a)
            ip("link", "set", self.dev_b, "netns", self.ns_b)
            for ns, dev, addr in ((self.ns_a, self.dev_a, self.addr_a), (self.ns_b, self.dev_b, self.addr_b)):
                ip("-n", ns, "addr", "add", f"{addr}/24", "dev", dev)
                ip("-n", ns, "link", "set", dev, "up")
        except BaseException:
            self.destroy()
            raise
        return self

    def destroy(self) -> None:
        """Remove both namespaces (the veth pair goes with them); idempotent."""
        ip("link", "del", self.dev_a, check=False)  # if it never moved into its namespace
        for ns in (self.ns_a, self.ns_b):
            ip("netns", "del", ns, check=False)
        self._made.clear()

    def set_link(self, side: str, up: bool) -> None:
        """Bring one side's veth up or down (``side`` 'a' or 'b'): down cuts the hosts apart."""
        ns, dev = (self.ns_a, self.dev_a) if side == "a" else (self.ns_b, self.dev_b)
        ip("-n", ns, "link", "set", dev, "up" if up else "down")

    def exec_argv(self, side: str, argv: list[str]) -> list[str]:
        """``argv`` run inside one namespace."""
        return ["ip", "netns", "exec", self.ns_a if side == "a" else self.ns_b, *argv]

    def __enter__(self) -> "HostPair":
        return self.create()

    def __exit__(self, *exc) -> None:
        self.destroy()
