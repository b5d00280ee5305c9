"""The force/torque sensor's twin: an ATI Net F/T on a robot's wrist (thesis §7.3; docs/design.md §11).

Device type ``netft`` (``[world.devices.NAME]``)::

    type = "netft"
    device = "netft://{loopback}:49152?http_port=8049"  # where it answers (a loopback address only);
                                                       # the subunit's droid-ft reads the same URL
    arm = "arm1"                  # the world device of the arm it sits on (has wcp_global())
    ft_pose = [0, 0, 100, 0, 0, 0]   # T_wcp_sensor: the sensor frame on the wrist (mm, ZYZ deg)
    sensor_tool_pose = [0, 0, 150, 0, 0, 0]     # T_sensor_tool: the tool point in the sensor frame
    tool_mass_kg = 1.5            # what hangs on the sensor (default 0)
    tool_com_mm = [0, 0, 60]      # its centre of mass in the sensor frame [mm]
    model = "gamma"               # the transducer: ranges, resolution, calibration (SENSOR_MODELS)
    rdt_rate_hz = 500.0           # RDT records a second while streaming
    seed = 7                      # default: [world] seed + 7

What it measures, in the sensor frame, is the load on its tool side:

* the tool's weight: ``tool_mass_kg`` x gravity (``GRAVITY_MPS2`` along the
  global -z), turned into the sensor frame by the arm's *true* wrist pose
  (``arm.wcp_global() @ ft_pose``, as the MVS camera twin takes its pose,
  :mod:`droid.sim.mvs.devices`), acting at ``tool_com_mm``;
* the contact wrench between tool and workpiece, from a hook the arm device
  may offer (the Reis arms do: droid.sim.contact, docs/contact.md)::

      arm.contact_wrench_N_Nm() -> (force[3] [N], torque[3] [N m])

  the wrench the environment applies to the tool, in the global frame, the
  torque about the tool point (``sensor_tool_pose``).  An arm without the method
  has no contact: zero (``getattr`` default);
* the transducer: Gaussian noise and a random-walk bias drift per axis, and
  saturation past the model's range (the reading held at the range, status
  ``0x80020000``: error summary + "transducer saturation", as the device).

It answers RDT requests on UDP (:mod:`droid.subunits.ft.rdt` has the wire):
start (0x0002/0x0003, ``sample_count`` records or until stopped), stop, set
software bias (0x0042: the present reading is subtracted from what follows);
records go to the address and port that sent the start, ``rdt_rate_hz``
times a second of *world* time (stepped from :meth:`NetFtTwinDevice.advance`,
never a thread), ``rdt_sequence`` from 1 per request, ``ft_sequence`` at the
device's 7000 samples a second.  Requests of the wrong size or header are
counted and ignored.  Its calibration page ``/netftapi2.xml`` is served by a
small threaded ``http.server`` on the URL's ``http_port``, stopped in
:meth:`close`.  Both sockets open on the world's first step, not when the
world is built (a cell-file check binds nothing); a port already taken is one
line on stderr and a retry every second of world time.

:class:`NetFtTwin` is the core (a true wrench and requests in, record bytes
out, seeded); :class:`NetFtTwinDevice` the world device with its sockets.
"""
from __future__ import annotations

import ipaddress
import socket
import sys
import threading
from dataclasses import dataclass, replace
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import numpy as np

from droid.brain.runtime.program import close_all
from droid.sim.device import Device
from droid.subunits.ft.rdt import (CALIBRATION_PATH, CMD_SET_BIAS, CMD_START_BUFFERED, CMD_START_REALTIME,
                                   CMD_STOP, FT_SAMPLES_PER_S, RDT_HEADER, RECORD, REQUEST, STATUS_ERROR,
                                   STATUS_SATURATION, Calibration, Record, parse_url)

#: standard gravity, along the global frame's -z [m/s^2] (the cell's global z points up: ASSUMED,
#: as the arms' bases in cells/sim.toml stand on z = 0)
GRAVITY_MPS2 = 9.80665
DEFAULT_RDT_RATE_HZ = 500.0  # ASSUMED: the Net F/T's RDT rate is set on its web page (up to 7000 Hz)
SEED_OFFSET = 7


@dataclass(frozen=True)
class SensorModel:
    """A transducer's numbers: range [N, N m] and noise per axis, drift, and its calibration page."""

    name: str
    range_: tuple[float, ...]  # Fx Fy Fz [N], Tx Ty Tz [N m]: saturation beyond
    noise: tuple[float, ...]  # 1-sigma per axis [N, N m]
    drift_per_sqrt_s: tuple[float, ...]  # random-walk bias drift, 1-sigma after 1 s [N, N m]
    calibration: Calibration
    source: str


# Values and their sources (docs/ft.md repeats them).
#  ranges, resolution: ATI's calibration tables for the Gamma SI-130-10 and Mini45 SI-290-10, as recalled
#    (Gamma: 130/130/400 N, 10/10/10 N m, resolution 1/40, 1/40, 1/20 N, 1/800 N m; Mini45: 290/290/580 N,
#    10/10/10 N m, 1/8 N, 1/376, 1/376, 1/752 N m) -- NOT checked against the datasheet in this session:
#    the search found the Net F/T and Axia manuals but not the transducer tables.
#  noise: ASSUMED 1-sigma = the resolution (ATI's resolution is the smallest change the system resolves).
#  drift: ASSUMED a random walk reaching one resolution step after 60 s.
#  calibration: N and N-mm, "the common ATI combination" (pyNetFT README); 1e6 counts/N and 1e3 counts/N-mm
#    ASSUMED (a typical Net F/T page; the driver reads whatever the page says).
_NET_CAL = Calibration(1e6, 1e3, "N", "N-mm", "Net F/T (DROID twin)")


def _model(name, rng, res, source) -> SensorModel:
    return SensorModel(name, tuple(rng), tuple(res), tuple(r / np.sqrt(60.0) for r in res),
                       replace(_NET_CAL, product=f"Net F/T {name} (DROID twin)"), source)


SENSOR_MODELS: dict[str, SensorModel] = {
    "gamma": _model("Gamma SI-130-10", (130, 130, 400, 10, 10, 10),
                    (1 / 40, 1 / 40, 1 / 20, 1 / 800, 1 / 800, 1 / 800),
                    "ATI Gamma SI-130-10 (recalled, unverified); noise, drift ASSUMED"),
    "mini45": _model("Mini45 SI-290-10", (290, 290, 580, 10, 10, 10),
                     (1 / 8, 1 / 8, 1 / 8, 1 / 376, 1 / 376, 1 / 752),
                     "ATI Mini45 SI-290-10 (recalled, unverified); noise, drift ASSUMED"),
}


class NetFtTwin:
    """The Net F/T as a core: requests and the true wrench in, RDT record bytes out (no I/O).

    ``step(dt_s, load)`` advances world time and returns the records due in that span (while
    streaming); ``load`` is the true wrench ``(force [N], torque [N m])`` or a function giving
    it, asked only when a record (or a bias) needs a reading.  ``request(bytes)`` carries out
    one RDT request."""

    def __init__(self, model: SensorModel, seed: int = 0, rdt_rate_hz: float = DEFAULT_RDT_RATE_HZ,
                 noisy: bool = True) -> None:
        if not rdt_rate_hz > 0:
            raise ValueError("rdt_rate_hz must be > 0")
        self.model = model
        self.cal = model.calibration
        self.rng = np.random.default_rng(seed)
        self.rate_hz = float(rdt_rate_hz)
        self.noisy = noisy
        self._noise = np.array(model.noise, float)
        self._drift_rate = np.array(model.drift_per_sqrt_s, float)
        self._range = np.array(model.range_, float)
        self._per_count = np.array([self.cal.n_per_count] * 3 + [self.cal.nm_per_count] * 3)
        self.t_ns = 0
        self._k = 0  # records due so far
        self.streaming = False
        self.remaining = 0  # records left of a counted request (0: until stopped)
        self.rdt_seq = 0
        self.drift = np.zeros(6)
        self.bias = np.zeros(6)
        self.truth = np.zeros(6)  # the true load now [N, N m]
        self.reading = np.zeros(6)  # the transducer's reading now (noise, drift, clipped) [N, N m]
        self.saturated = False
        self._unmeasured_s = 0.0  # world time since the last reading (the drift's step) [s]
        self._bias_pending = False
        self.bad_requests = 0
        self.sent = 0

    @property
    def ft_seq(self) -> int:
        return (self.t_ns * FT_SAMPLES_PER_S // 1_000_000_000) & 0xFFFFFFFF

    def request(self, data: bytes) -> int | None:
        """Carry out one request; its command, or None for a malformed one (counted)."""
        if len(data) != REQUEST.size:
            self.bad_requests += 1
            return None
        header, command, count = REQUEST.unpack(data)
        if header != RDT_HEADER:
            self.bad_requests += 1
            return None
        if command in (CMD_START_REALTIME, CMD_START_BUFFERED):
            self.streaming, self.remaining, self.rdt_seq = True, count, 0
        elif command == CMD_STOP:
            self.streaming = False
        elif command == CMD_SET_BIAS:
            self._bias_pending = True  # the reading at the next step
        else:
            self.bad_requests += 1
            return None
        return command

    def _measure(self) -> None:
        dt_s, self._unmeasured_s = self._unmeasured_s, 0.0
        raw = self.truth
        if self.noisy:
            z = self.rng.standard_normal(12)
            self.drift += z[:6] * self._drift_rate * np.sqrt(dt_s)
            raw = raw + self.drift + z[6:] * self._noise
        lim = self._range
        self.saturated = bool((np.abs(raw) > lim).any())
        self.reading = np.minimum(np.maximum(raw, -lim), lim)

    def record(self) -> bytes:
        """The next record of the stream (the reading less the bias, in counts)."""
        self.rdt_seq = (self.rdt_seq + 1) & 0xFFFFFFFF
        c = np.rint((self.reading - self.bias) / self._per_count)
        counts = tuple(np.minimum(np.maximum(c, -2**31), 2**31 - 1).astype(np.int64).tolist())
        status = (STATUS_ERROR | STATUS_SATURATION) if self.saturated else 0
        self.sent += 1
        return Record(self.rdt_seq, self.ft_seq, status, counts).pack()

    def step(self, dt_s: float, load=((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))) -> list[bytes]:
        """Advance ``dt_s`` of world time under the true ``load``; the records due meanwhile."""
        self.t_ns += int(round(dt_s * 1e9))
        self._unmeasured_s += dt_s
        due = int(self.t_ns * self.rate_hz // 1e9)
        n, self._k = max(0, due - self._k), max(self._k, due)
        if (n and self.streaming) or self._bias_pending:
            force_N, torque_Nm = load() if callable(load) else load
            self.truth = np.array([*force_N, *torque_Nm], float)
            self._measure()
            if self._bias_pending:
                self.bias, self._bias_pending = self.reading.copy(), False
        out = []
        for _ in range(n if self.streaming else 0):
            out.append(self.record())
            if self.remaining:
                self.remaining -= 1
                if self.remaining == 0:
                    self.streaming = False
                    break
        return out


def wrench_on_sensor(T_global_sensor: np.ndarray, T_sensor_tool: np.ndarray, tool_mass_kg: float,
                     tool_com_mm, contact=None) -> tuple[np.ndarray, np.ndarray]:
    """The true load on the sensor, in its frame: the tool's weight at its centre of mass plus
    the contact wrench ``(force [N], torque [N m] about the tool point)`` given in the global frame."""
    R = np.asarray(T_global_sensor, float)[:3, :3]
    f = R.T @ np.array([0.0, 0.0, -GRAVITY_MPS2 * tool_mass_kg])
    m = _cross(np.asarray(tool_com_mm, float) * 1e-3, f)
    if contact is not None:
        fc = R.T @ np.asarray(contact[0], float)
        mc = R.T @ np.asarray(contact[1], float)
        f = f + fc
        m = m + mc + _cross(np.asarray(T_sensor_tool, float)[:3, 3] * 1e-3, fc)
    return f, m


def _cross(a, b) -> np.ndarray:
    """a x b of two 3-vectors (numpy's cross costs ~50 us a call: too much at the world's 1 kHz)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


class _PageHandler(BaseHTTPRequestHandler):
    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        if self.path.split("?")[0] != CALIBRATION_PATH:
            self.send_error(404)
            return
        body = self.server.page  # type: ignore[attr-defined]
        self.send_response(200)
        self.send_header("Content-Type", "text/xml")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Connection", "close")
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args) -> None:
        pass


class _PageServer(ThreadingHTTPServer):
    allow_reuse_address = True
    daemon_threads = True


class CalibrationPage:
    """``/netftapi2.xml`` on a small threaded HTTP server (loopback); ``page`` may be replaced
    (a test serves a garbled one)."""

    def __init__(self, host: str, port: int, page: bytes) -> None:
        self.server = _PageServer((host, port), _PageHandler)
        self.server.page = page  # type: ignore[attr-defined]
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05},
                                       name=f"netft-http-{self.port}", daemon=True)
        self.thread.start()

    @property
    def page(self) -> bytes:
        return self.server.page  # type: ignore[attr-defined]

    @page.setter
    def page(self, body: bytes) -> None:
        self.server.page = body  # type: ignore[attr-defined]

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        self.thread.join(timeout=2.0)


class NetFtTwinDevice(Device):
    """The twin in the world: the core, the arm it sits on, a UDP socket and the calibration page.

    The sockets are opened by :meth:`serve`, which :meth:`advance` calls on the world's first
    step (and again once a second of world time while it fails): building a world and closing
    it (the cell-file checks) binds nothing.  A port another program holds (a second simulated
    cell on this host with the same URL) is one line on stderr, not a dead world."""

    #: most requests read in one step
    MAX_REQUESTS_PER_STEP = 64
    #: how often a failed serve() is tried again [s of world time]
    RETRY_S = 1.0

    def __init__(self, name: str, twin: NetFtTwin, arm, T_wcp_sensor, T_sensor_tool, tool_mass_kg: float,
                 tool_com_mm, host: str = "127.0.0.1", port: int = 0, http_port: int = 0, log=None) -> None:
        self.name = name
        self.twin = twin
        # advanced once per RDT record at most (250 Hz: 4 ms), never less often than every 4 ms
        # (requests answered, the contact's wrench sampled): its records keep the RDT rate
        self.step_s = min(0.004, 1.0 / twin.rate_hz) if twin.rate_hz > 0 else 0.0
        self.arm = arm
        self.T_wcp_sensor = np.asarray(T_wcp_sensor, float)
        self.T_sensor_tool = np.asarray(T_sensor_tool, float)
        self.tool_mass_kg = float(tool_mass_kg)
        self.tool_com_mm = np.asarray(tool_com_mm, float)
        self.host, self.port, self.http_port = host, int(port), int(http_port)
        self.log = log or (lambda line: print(f"droid-sim: {line}", file=sys.stderr, flush=True))
        self.client: tuple | None = None
        self.send_errors = 0
        self.sock: socket.socket | None = None
        self.page: CalibrationPage | None = None
        self.serve_error = ""
        self._retry_in_s = 0.0
        self._seen: tuple | None = None  # (wrist pose and contact key, true wrench) of true_wrench's last answer

    def serve(self) -> None:
        """Bind the RDT socket and start the calibration page (OSError if a port is taken);
        port 0 picks a free one (``port``/``http_port``/``url`` say which)."""
        if self.sock is not None:
            return
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((self.host, self.port))
            sock.setblocking(False)
            self.page = CalibrationPage(self.host, self.http_port, self.twin.cal.xml())
        except OSError:
            sock.close()
            raise
        self.sock = sock
        self.port = sock.getsockname()[1]
        self.http_port = self.page.port

    @property
    def url(self) -> str:
        return f"netft://{self.host}:{self.port}?http_port={self.http_port}"

    def true_wrench(self) -> tuple[np.ndarray, np.ndarray]:
        """The true load on the sensor now, in the sensor frame [N, N m] (the world's truth)."""
        hook = getattr(self.arm, "contact_wrench_N_Nm", None)
        contact = hook() if callable(hook) else None
        wcp = np.asarray(self.arm.wcp_global())
        # a function of the wrist's pose, the contact wrench and the tool alone: unchanged to the
        # bit (the arm at rest, no contact), the load is the one computed last time
        key = (wcp.dtype.str, wcp.tobytes(), None if contact is None else
               tuple((np.asarray(v).dtype.str, np.asarray(v).tobytes()) for v in contact),
               self.tool_mass_kg, self.tool_com_mm.tobytes(), self.T_wcp_sensor.tobytes(), self.T_sensor_tool.tobytes())
        seen = self._seen
        if seen is None or seen[0] != key:
            T_gs = wcp @ self.T_wcp_sensor
            seen = self._seen = (key, wrench_on_sensor(T_gs, self.T_sensor_tool, self.tool_mass_kg,
                                                       self.tool_com_mm, contact))
        f, m = seen[1]
        return f.copy(), m.copy()

    def _try_serve(self, dt_s: float) -> None:
        self._retry_in_s -= dt_s
        if self._retry_in_s > 0:
            return
        self._retry_in_s = self.RETRY_S
        try:
            self.serve()
        except OSError as exc:
            line = (f"netft twin {self.name}: cannot serve {self.host}:{self.port} (RDT) and "
                    f"{self.http_port} (HTTP): {exc.strerror or exc}; retrying every {self.RETRY_S:g} s")
            if line != self.serve_error:
                self.serve_error = line
                self.log(line)

    def advance(self, dt_s: float) -> None:
        if self.sock is None:
            self._try_serve(dt_s)
        sock = self.sock
        for _ in range(self.MAX_REQUESTS_PER_STEP if sock is not None else 0):
            try:
                data, addr = sock.recvfrom(64)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self.send_errors += 1
                break
            cmd = self.twin.request(data)
            if cmd in (CMD_START_REALTIME, CMD_START_BUFFERED):
                self.client = addr  # records go to whoever sent the start
        for rec in self.twin.step(dt_s, self.true_wrench):
            if sock is None or self.client is None:
                break
            try:
                sock.sendto(rec, self.client)
            except OSError:  # full buffer, nobody there: the record is lost, as on a network
                self.send_errors += 1

    def close(self) -> None:
        page, sock, self.page, self.sock = self.page, self.sock, None, None
        close_all(page, sock)


def make_netft(world, name: str, options: dict[str, Any]) -> NetFtTwinDevice:
    """Factory for ``type = "netft"`` (droid.sim.world.DEVICE_TYPES)."""
    from droid.sim.device_options import DeviceOptions

    opts = DeviceOptions(world, name, options)
    url = parse_url(opts.get("device", str), any_port=True)
    host = "127.0.0.1" if url.host == "localhost" else url.host
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        raise opts.bad(f"the twin answers on a loopback address only (127.0.0.0/8), not {url.host!r}", "device")
    arm = opts.device("arm")
    T_wcp_sensor = opts.pose("ft_pose", [0.0] * 6)
    T_sensor_tool = opts.pose("sensor_tool_pose", [0.0] * 6)
    mass = opts.get("tool_mass_kg", float, 0.0, check=lambda v: None if v >= 0 else "must be >= 0 kg")
    com = opts.get("tool_com_mm", list, [0.0, 0.0, 0.0],
                   check=lambda v: None if len(v) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                               for x in v) else "must be 3 numbers [mm]")
    model_name = opts.get("model", str, "gamma", check=lambda v: None if v in SENSOR_MODELS else
                          f"unknown model (known: {', '.join(SENSOR_MODELS)})")
    rate = opts.get("rdt_rate_hz", float, DEFAULT_RDT_RATE_HZ,
                    check=lambda v: None if 0 < v <= FT_SAMPLES_PER_S else f"must be in (0, {FT_SAMPLES_PER_S}] Hz")
    seed = opts.get("seed", int, int(getattr(world, "seed", 0)) + SEED_OFFSET)
    opts.done()
    twin = NetFtTwin(SENSOR_MODELS[model_name], seed, rate)
    return NetFtTwinDevice(name, twin, arm, T_wcp_sensor, T_sensor_tool, mass, [float(x) for x in com],
                           host, url.port, url.http_port)


#: RECORD is the record the twin writes (re-exported for tests)
__all__ = ["NetFtTwin", "NetFtTwinDevice", "SENSOR_MODELS", "make_netft", "wrench_on_sensor", "RECORD"]
