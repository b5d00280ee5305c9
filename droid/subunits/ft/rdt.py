"""ATI Net F/T over Ethernet: RDT on UDP and the calibration page on HTTP (thesis §7.3; docs/design.md §11).

URL (the ``device`` key of an ``ft6`` subunit)::

    netft://HOST[:PORT][?rate_hz=HZ&http_port=N&bias=0|1]

``PORT`` is the RDT port (49152, ATI's default); ``rate_hz`` is how often
``droid-ft`` reads and writes its Status (1..1000 Hz, default 100; the device
streams at the RDT rate configured on it and every record is checked, the
newest one is published); ``http_port`` serves ``/netftapi2.xml`` (80);
``bias = 1`` sets the software bias once the stream runs.  An unknown scheme
or option is refused with the expected form (exit 2).

The wire (ATI Net F/T manual 9620-05-NET FT, "UDP Interface Using RDT"; the
same in the Ethernet Axia manual 9610-05-Ethernet Axia, §12; checked against
the independent client pyNetFT 2.1.3, netft-cpp core ``protocol.cpp``):

* request, 8 bytes big-endian: ``uint16 0x1234, uint16 command, uint32
  sample_count`` (0 = until told to stop); commands 0x0000 stop, 0x0002
  start real-time streaming, 0x0003 start buffered, 0x0042 set software bias;
  the device answers the address and port that sent the command;
* record, 36 bytes big-endian: ``uint32 rdt_sequence`` (1, 2, ... within one
  request; wraps at 2^32), ``uint32 ft_sequence`` (the device's internal
  sample number, 7000 a second, not reset by a request), ``uint32 status``,
  ``int32 Fx Fy Fz Tx Ty Tz`` [counts].
* calibration (HTTP GET ``/netftapi2.xml``): ``cfgcpf`` counts per force
  unit, ``cfgcpt`` counts per torque unit, ``scfgfu``/``scfgtu`` the unit
  names (pyNetFT reads the same four elements, plus ``prodname``); force =
  counts / cfgcpf [force unit], torque = counts / cfgcpt [torque unit],
  converted here to N and N m (:data:`FORCE_UNITS_N`, :data:`TORQUE_UNITS_NM`).

:class:`RdtStream` is the core (datagrams in, checked records out: dropped
and out-of-order records and bad datagrams counted, never raised);
:class:`NetFtDevice` the I/O (a connected non-blocking UDP socket).
"""
from __future__ import annotations

import http.client
import math
import socket
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from urllib.parse import parse_qsl, urlsplit

from droid.cli import BadInput, RuntimeFailure
from droid.numbers import Range

# --- the RDT wire
RDT_PORT = 49152
RDT_HEADER = 0x1234
REQUEST = struct.Struct(">HHI")  # header, command, sample_count
RECORD = struct.Struct(">III6i")  # rdt_sequence, ft_sequence, status, Fx Fy Fz Tx Ty Tz [counts]
CMD_STOP = 0x0000
CMD_START_REALTIME = 0x0002
CMD_START_BUFFERED = 0x0003
CMD_SET_BIAS = 0x0042
#: status bits (Net F/T manual, "System Status Code"; pyNetFT status.cpp)
STATUS_ERROR = 0x80000000  # error summary
STATUS_SATURATION = 0x00020000  # transducer saturation or A/D error
#: the device's internal sample rate: ft_sequence counts these [1/s]
FT_SAMPLES_PER_S = 7000
CALIBRATION_PATH = "/netftapi2.xml"
HTTP_PORT = 80
#: the calibration page's size limit [bytes] (pyNetFT: 65536)
MAX_PAGE_BYTES = 65536
#: newton per force unit, N m per torque unit (the spellings of the XML page and of pyNetFT)
LBF_N = 4.4482216152605
FORCE_UNITS_N = {"N": 1.0, "lbf": LBF_N, "klbf": 1000.0 * LBF_N, "kN": 1000.0, "kgf": 9.80665}
TORQUE_UNITS_NM = {"N-m": 1.0, "Nm": 1.0, "N-mm": 1e-3, "Nmm": 1e-3, "lbf-in": LBF_N * 0.0254,
                   "lbf-ft": LBF_N * 0.3048, "kgf-cm": 9.80665e-2, "kg-cm": 9.80665e-2, "kN-m": 1000.0}

#: droid-ft's read rates (``rate_hz`` of the URL) [Hz]
RATE_HZ = Range(1.0, 1000.0, "Hz")
DEFAULT_RATE_HZ = 100.0
PORT = Range(1, 65535, integral=True)
PORT_OR_ANY = Range(0, 65535, integral=True)
#: the HTTP request's time limit [s]
HTTP_TIMEOUT_S = 0.5
#: most datagrams read in one poll (bounded: a flood cannot hold the loop)
MAX_DATAGRAMS_PER_POLL = 4096


def request(command: int, count: int = 0) -> bytes:
    """An RDT request (8 bytes)."""
    return REQUEST.pack(RDT_HEADER, command, count)


class CalibrationError(RuntimeFailure):
    """The calibration page is missing, unreachable or garbled (one line)."""


@dataclass(frozen=True)
class Calibration:
    """Counts per force/torque unit and the units, as the device publishes them."""

    counts_per_force: float
    counts_per_torque: float
    force_unit: str = "N"
    torque_unit: str = "N-m"
    product: str = ""

    @property
    def n_per_count(self) -> float:
        return FORCE_UNITS_N[self.force_unit] / self.counts_per_force

    @property
    def nm_per_count(self) -> float:
        return TORQUE_UNITS_NM[self.torque_unit] / self.counts_per_torque

    def xml(self) -> bytes:
        """The page as the device serves it (the elements a client reads)."""
        return (f'<?xml version="1.0" encoding="utf-8"?>\n<netft>\n<prodname>{self.product}</prodname>\n'
                f"<cfgcpf>{self.counts_per_force:g}</cfgcpf>\n<cfgcpt>{self.counts_per_torque:g}</cfgcpt>\n"
                f"<scfgfu>{self.force_unit}</scfgfu>\n<scfgtu>{self.torque_unit}</scfgtu>\n</netft>\n"
                ).encode("ascii")


def parse_calibration(page: bytes, where: str = CALIBRATION_PATH) -> Calibration:
    """The calibration of a ``netftapi2.xml`` page; :class:`CalibrationError` naming what is wrong."""
    if len(page) > MAX_PAGE_BYTES:
        raise CalibrationError(f"calibration {where}: page larger than {MAX_PAGE_BYTES} bytes")
    try:
        root = ET.fromstring(page)
    except ET.ParseError as exc:
        raise CalibrationError(f"calibration {where}: not XML ({exc})") from None

    def text(tag: str) -> str:
        found = root.findall(f".//{tag}") if root.tag != tag else [root]
        if len(found) != 1:
            raise CalibrationError(f"calibration {where}: <{tag}> must appear exactly once "
                                   f"(found {len(found)})")
        return (found[0].text or "").strip()

    def count(tag: str) -> float:
        raw = text(tag)
        try:
            value = float(raw)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value > 0):
            raise CalibrationError(f"calibration {where}: <{tag}> {raw[:40]!r} is not a finite number > 0")
        return value

    cpf, cpt = count("cfgcpf"), count("cfgcpt")
    fu, tu = text("scfgfu"), text("scfgtu")
    if fu not in FORCE_UNITS_N:
        raise CalibrationError(f"calibration {where}: unknown force unit {fu[:20]!r} "
                               f"(known: {', '.join(FORCE_UNITS_N)})")
    if tu not in TORQUE_UNITS_NM:
        raise CalibrationError(f"calibration {where}: unknown torque unit {tu[:20]!r} "
                               f"(known: {', '.join(TORQUE_UNITS_NM)})")
    prod = root.find(".//prodname")
    return Calibration(cpf, cpt, fu, tu, (prod.text or "").strip() if prod is not None else "")


def fetch_calibration(host: str, http_port: int = HTTP_PORT, timeout_s: float = HTTP_TIMEOUT_S) -> Calibration:
    """GET ``http://HOST:PORT/netftapi2.xml`` and parse it; :class:`CalibrationError` (one line)."""
    where = f"http://{host}:{http_port}{CALIBRATION_PATH}"
    conn = http.client.HTTPConnection(host, http_port, timeout=timeout_s)
    try:
        conn.request("GET", CALIBRATION_PATH, headers={"Connection": "close"})
        resp = conn.getresponse()
        body = resp.read(MAX_PAGE_BYTES + 1)
        if resp.status != 200:
            raise CalibrationError(f"calibration {where}: HTTP {resp.status}")
    except (OSError, http.client.HTTPException) as exc:
        raise CalibrationError(f"calibration {where}: {exc.__class__.__name__}: {exc}") from None
    finally:
        conn.close()
    return parse_calibration(body, where)


@dataclass(frozen=True)
class Record:
    """One RDT record: sequence numbers, status and the six counts."""

    rdt_seq: int
    ft_seq: int
    status: int
    counts: tuple[int, int, int, int, int, int]

    def pack(self) -> bytes:
        return RECORD.pack(self.rdt_seq & 0xFFFFFFFF, self.ft_seq & 0xFFFFFFFF, self.status, *self.counts)


class RdtStream:
    """Checks RDT datagrams (no I/O): one 36-byte record each, ``rdt_sequence`` one more than
    the last applied.  A gap counts the missing records in ``dropped`` (the record is applied);
    a record not newer than the last applied (mod 2^32) counts in ``out_of_order`` and is not
    applied; a datagram of another size, or from another sender, counts in ``bad_datagrams``.
    :meth:`restart` forgets the sequence (a new request starts at 1)."""

    def __init__(self) -> None:
        self.last: Record | None = None
        self.dropped = 0
        self.out_of_order = 0
        self.bad_datagrams = 0
        self.records = 0
        self._seq: int | None = None

    def restart(self) -> None:
        self._seq = None

    def feed(self, datagram: bytes) -> Record | None:
        """Apply one datagram; the record if it was applied, else None (counted)."""
        if len(datagram) != RECORD.size:
            self.bad_datagrams += 1
            return None
        rdt, ft, status, *counts = RECORD.unpack(datagram)
        if self._seq is not None:
            delta = (rdt - self._seq) & 0xFFFFFFFF
            if delta == 0 or delta >= 0x80000000:
                self.out_of_order += 1
                return None
            self.dropped += delta - 1
        self._seq = rdt
        self.records += 1
        self.last = Record(rdt, ft, status, tuple(counts))
        return self.last


@dataclass(frozen=True)
class NetFtUrl:
    host: str
    port: int
    rate_hz: float
    http_port: int
    bias: bool


FORM = "expected netft://HOST[:PORT][?rate_hz=HZ&http_port=N&bias=0|1]"


def parse_url(url: str, *, any_port: bool = False) -> NetFtUrl:
    """The parts of a ``netft://`` URL; BadInput with the expected form.  ``any_port``: port 0
    (a server's "any free port", for the twin in tests) is allowed."""
    parts = urlsplit(url)
    if parts.scheme not in DRIVERS or not parts.hostname or parts.path not in ("", "/"):
        raise BadInput(f"force/torque device {url!r}: {FORM}")
    try:
        port = parts.port if parts.port is not None else RDT_PORT
        opts = dict(parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query)))
    except ValueError:
        raise BadInput(f"force/torque device {url!r}: bad port or options; {FORM}") from None
    unknown = sorted(set(opts) - {"rate_hz", "http_port", "bias"})
    if unknown:
        raise BadInput(f"force/torque device {url!r}: unknown option {unknown[0]!r} "
                       f"(allowed: rate_hz, http_port, bias)")

    def number(key: str, rng: Range, default, conv, raw=None):
        raw = opts.get(key) if raw is None else raw
        if raw is None:
            return default
        try:
            return rng.check(conv(raw), key)
        except (ValueError, ArithmeticError) as exc:
            why = str(exc) if "=" in str(exc) else f"{key} = {raw!r}: must be in {rng.span}"
            raise BadInput(f"force/torque device {url!r}: {why}") from None

    ports = PORT_OR_ANY if any_port else PORT
    port = number("port", ports, RDT_PORT, int, str(port)) if parts.port is not None else port
    rate = number("rate_hz", RATE_HZ, DEFAULT_RATE_HZ, float)
    http_port = number("http_port", ports, HTTP_PORT, int)
    bias = opts.get("bias", "0")
    if bias not in ("0", "1"):
        raise BadInput(f"force/torque device {url!r}: bias must be 0 or 1")
    return NetFtUrl(parts.hostname, port, rate, http_port, bias == "1")


class NetFtDevice:
    """A Net F/T on UDP (see the module doc): :meth:`start`, :meth:`poll`, :meth:`bias`,
    :meth:`stop`; the calibration by :meth:`calibrate` (HTTP).  Never raises on the wire:
    socket errors are counted in ``errors`` with ``last_error``."""

    scheme = "netft"

    def __init__(self, url: NetFtUrl) -> None:
        self.url = url
        self.stream = RdtStream()
        self.calibration: Calibration | None = None
        self.biased = False
        self.errors = 0
        self.last_error = ""
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        try:
            self.sock.connect((url.host, url.port))  # the kernel drops datagrams from anyone else
        except OSError as exc:
            self.sock.close()
            raise BadInput(f"force/torque device {url.host}:{url.port}: {exc.strerror or exc}") from None

    def calibrate(self) -> Calibration:
        """Fetch the calibration page (CalibrationError: one line)."""
        self.calibration = fetch_calibration(self.url.host, self.url.http_port)
        return self.calibration

    def _send(self, data: bytes) -> bool:
        try:
            self.sock.send(data)
            return True
        except OSError as exc:
            self.errors += 1
            self.last_error = f"{self.url.host}:{self.url.port}: {exc.strerror or exc}"
            return False

    def start(self) -> bool:
        """Ask for real-time streaming until stopped (a new request: the sequence restarts)."""
        self.stream.restart()
        self.biased = False
        return self._send(request(CMD_START_REALTIME, 0))

    def bias(self) -> bool:
        """Set the software bias: the device subtracts its present reading from what follows."""
        ok = self._send(request(CMD_SET_BIAS, 0))
        self.biased = self.biased or ok
        return ok

    def stop(self) -> bool:
        return self._send(request(CMD_STOP, 0))

    def poll(self) -> list[Record]:
        """Every datagram waiting, checked (:class:`RdtStream`); the records applied, oldest first."""
        out = []
        for _ in range(MAX_DATAGRAMS_PER_POLL):
            try:
                data = self.sock.recv(RECORD.size + 1)  # one byte more: an oversized datagram shows
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:  # ECONNREFUSED: nobody listens (yet) on the device's port
                self.errors += 1
                self.last_error = f"{self.url.host}:{self.url.port}: {exc.strerror or exc}"
                break
            rec = self.stream.feed(data)
            if rec is not None:
                out.append(rec)
        return out

    def close(self) -> None:
        if self.sock.fileno() >= 0:
            self.stop()
            self.sock.close()


#: URL scheme -> driver class (the handler table; droid.brain.cell.classes names the same)
DRIVERS: dict[str, type[NetFtDevice]] = {"netft": NetFtDevice}


def open_ft(url: str) -> NetFtDevice:
    """The driver for ``url`` (socket open, not yet streaming: call :meth:`NetFtDevice.start`)."""
    parsed = parse_url(url)
    return DRIVERS[urlsplit(url).scheme](parsed)
