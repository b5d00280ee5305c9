"""Authenticated, encrypted links between hosts: ZeroMQ CURVE (docs/design.md §4; thesis §7.1).

The thesis's cell trusted its own network; its §7.1 looks ahead to reaching
the Brain remotely.  A link that leaves a host can be protected with CURVE
(CurveZMQ: Curve25519 key exchange, encrypted and authenticated frames) when
the cell file names keys::

    [curve]
    keys = "/etc/droid/keys"        # directory written by droid-keys (relative: to the cell file)
    hosts = { brain = "brain" }     # key of each host (default: the key named after the host)
    allow = ["operator"]            # further client keys let in (default: none)

Every host of the cell has a key pair in that directory: ``NAME.key`` (public)
and ``NAME.key_secret`` (secret, mode 0600, needed only on that host).  A
program uses the key of the host it runs on (Brain programs: ``[brain] host``;
a subunit's programs: its ``host``).

* A socket that *binds* a ``tcp://`` endpoint (heartbeat PUB, name-space
  ROUTER, agent ROUTER, relay PUB, servo PULL/PUB) is a CURVE server with its
  host's secret key, and a ZAP handler (:class:`zmq.auth.thread.ThreadAuthenticator`)
  lets in only clients whose public key belongs to the cell: the keys of its
  hosts and those in ``allow``.  A client with another key, no key or a wrong
  idea of the server's key fails the handshake: it receives nothing and
  nothing it sends is delivered.
* A socket that *connects* to a ``tcp://`` endpoint is a CURVE client with its
  host's key pair and the server host's public key.

``ipc://`` and ``inproc://`` endpoints never use CURVE: they do not leave the
host, and the run directory's permissions guard them.  A cell file without a
``[curve]`` table uses no keys at all.
"""
from __future__ import annotations

import os
import stat
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth

from droid.cli import BadInput

PUBLIC_SUFFIX = ".key"
SECRET_SUFFIX = ".key_secret"
SECURE_SCHEMES = ("tcp://",)  # endpoints that leave the host


@dataclass(frozen=True)
class CurveConfig:
    """The cell file's ``[curve]`` table, validated (see the module docstring)."""

    keys: Path  # key directory
    host_keys: dict[str, str]  # host -> key name, for every host of the cell
    allow: tuple[str, ...] = ()  # further client key names let in

    def key_name(self, host: str) -> str:
        return self.host_keys.get(host, host)

    def allowed_names(self) -> list[str]:
        """Key names whose holders may connect: every host's, then ``allow``."""
        return sorted(set(self.host_keys.values()) | set(self.allow))

    def public_path(self, name: str) -> Path:
        return self.keys / f"{name}{PUBLIC_SUFFIX}"

    def secret_path(self, name: str) -> Path:
        return self.keys / f"{name}{SECRET_SUFFIX}"


def secured(endpoint: str) -> bool:
    """True for endpoints that leave the host (``tcp://``), which CURVE protects."""
    return endpoint.startswith(SECURE_SCHEMES)


def load_public_key(path: Path) -> bytes:
    """The Z85 public key in a zmq.auth key file (public or secret); BadInput if unreadable."""
    try:
        public, _ = zmq.auth.load_certificate(path)
    except (OSError, ValueError) as exc:
        raise BadInput(f"CURVE key {path}: cannot read ({_reason(exc)}); make it with droid-keys") from None
    return public


def load_key_pair(path: Path) -> tuple[bytes, bytes]:
    """(public, secret) Z85 keys from a ``NAME.key_secret`` file that only its owner can read."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise BadInput(f"CURVE secret key {path}: cannot read ({_reason(exc)}); "
                       f"make it with droid-keys") from None
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise BadInput(f"CURVE secret key {path} is accessible by others "
                       f"(mode {stat.S_IMODE(st.st_mode):04o}); chmod 600 it")
    try:
        public, secret = zmq.auth.load_certificate(path)
    except (OSError, ValueError) as exc:
        raise BadInput(f"CURVE secret key {path}: cannot read ({_reason(exc)})") from None
    if not secret:
        raise BadInput(f"CURVE secret key {path} holds no secret key")
    return public, secret


def _reason(exc: Exception) -> str:
    return getattr(exc, "strerror", None) or (str(exc).splitlines() or [type(exc).__name__])[0]


class CurveHost:
    """The CURVE keys of the programs on one host of a cell (or none: the cell names no keys).

    ``server(sock, endpoint)`` before a bind, ``client(sock, endpoint, server_host)``
    before a connect; both do nothing for ``ipc://`` endpoints or a cell without
    ``[curve]``.  The first secured server starts the ZAP handler thread;
    :meth:`close` stops it and must come before ``ctx.term()``.
    """

    def __init__(self, ctx: zmq.Context, cell, host: str) -> None:
        self.ctx = ctx
        self.config: CurveConfig | None = getattr(cell, "curve", None)
        self.domain = f"droid.{cell.name}"
        self.host = host
        self._pair: tuple[bytes, bytes] | None = None
        self._publics: dict[str, bytes] = {}
        self._auth = None

    @property
    def enabled(self) -> bool:
        return self.config is not None

    def _own_pair(self) -> tuple[bytes, bytes]:
        if self._pair is None:
            self._pair = load_key_pair(self.config.secret_path(self.config.key_name(self.host)))
        return self._pair

    def _public_of(self, name: str) -> bytes:
        if name not in self._publics:
            self._publics[name] = load_public_key(self.config.public_path(name))
        return self._publics[name]

    def allowed_keys(self) -> set[bytes]:
        """Z85 public keys of every client the cell lets in."""
        return {self._public_of(n) for n in self.config.allowed_names()}

    def server(self, sock: zmq.Socket, endpoint: str) -> bool:
        """Make ``sock`` a CURVE server if ``endpoint`` leaves the host; True if it did."""
        if not (self.enabled and secured(endpoint)):
            return False
        public, secret = self._own_pair()
        self._start_auth()
        sock.curve_secretkey = secret
        sock.curve_publickey = public
        sock.curve_server = True
        sock.zap_domain = self.domain.encode()
        return True

    def bind(self, cell, *socks_endpoints: tuple[zmq.Socket, str]) -> None:
        """Serve each ``(socket, endpoint)`` (CURVE where it leaves the host) and bind it where the
        cell says its owner binds (``cell.bind_endpoint``); RuntimeFailure (exit 1) naming the
        endpoints if one cannot be bound.  The one bind of every server socket of a program."""
        from droid.cli import RuntimeFailure

        for sock, endpoint in socks_endpoints:
            self.server(sock, endpoint)
        try:
            for sock, endpoint in socks_endpoints:
                sock.bind(cell.bind_endpoint(endpoint))
        except zmq.ZMQError as exc:
            names = " / ".join(ep for _, ep in socks_endpoints)
            raise RuntimeFailure(f"cannot bind {names}: {exc}") from None

    def client(self, sock: zmq.Socket, endpoint: str, server_host: str) -> bool:
        """Make ``sock`` a CURVE client of ``server_host``'s key if ``endpoint`` leaves the host."""
        if not (self.enabled and secured(endpoint)):
            return False
        public, secret = self._own_pair()
        sock.curve_secretkey = secret
        sock.curve_publickey = public
        sock.curve_serverkey = self._public_of(self.config.key_name(server_host))
        return True

    def _start_auth(self) -> None:
        if self._auth is not None:
            return
        from zmq.auth.thread import ThreadAuthenticator

        allowed = self.allowed_keys()

        class _CellKeys:
            def callback(self, domain: str, key: bytes) -> bool:
                return key in allowed

        auth = ThreadAuthenticator(self.ctx)
        auth.start()
        auth.configure_curve_callback(self.domain, credentials_provider=_CellKeys())
        self._auth = auth

    def close(self) -> None:
        """Stop the ZAP handler (if one runs); call before ``ctx.term()``."""
        if self._auth is not None:
            self._auth.stop()
            self._auth = None


def parse_curve_table(table: dict, path: Path, hosts: list[str], expand) -> CurveConfig:
    """Validate a cell file's ``[curve]`` table (``expand`` does ``{run}``/``{cell}``)."""
    from droid.brain.db.shmdb import check_name_part

    where = f"{path}: [curve]"
    if not isinstance(table, dict):
        raise BadInput(f"{where} must be a table")
    extra = set(table) - {"keys", "hosts", "allow"}
    if extra:
        raise BadInput(f"{where} unknown key(s): {', '.join(sorted(extra))}")
    keys = table.get("keys")
    if not isinstance(keys, str) or not keys:
        raise BadInput(f"{where} needs 'keys', the key directory written by droid-keys")
    key_dir = Path(expand(keys))
    if not key_dir.is_absolute():
        key_dir = path.resolve().parent / key_dir
    named = table.get("hosts", {})
    if not isinstance(named, dict):
        raise BadInput(f"{where} hosts must be a table of host = \"key name\"")
    unknown = set(named) - set(hosts)
    if unknown:
        raise BadInput(f"{where} hosts: unknown host(s) {', '.join(sorted(unknown))} "
                       f"(cell hosts: {', '.join(hosts)})")
    host_keys = {}
    for h in hosts:
        name = named.get(h, h)
        try:
            host_keys[h] = check_name_part(name, "key")
        except BadInput as exc:
            raise BadInput(f"{where} hosts.{h}: {exc}") from None
    allow = table.get("allow", [])
    if not isinstance(allow, list):
        raise BadInput(f"{where} allow must be a list of key names")
    for name in allow:
        try:
            check_name_part(name, "key")
        except BadInput as exc:
            raise BadInput(f"{where} allow: {exc}") from None
    return CurveConfig(key_dir, host_keys, tuple(allow))
