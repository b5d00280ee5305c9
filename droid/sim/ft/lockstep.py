"""The F/T sensor in lockstep: the Net F/T twin's core and droid-ft's station on one scheduler.

The twin (:class:`droid.sim.ft.netft.NetFtTwin`) is stepped in world time at ``TWIN_HZ``
and streams its RDT records; droid-ft's cycle, :class:`FtStation` (calibrate, start, read
everything waiting, restart a silent stream, bias when the Command asks) with
:class:`FtGuard` (the over-force guard: FAULT_FORCE in the guarded arm's Status), runs at
droid-ft's rate on :class:`TwinNetFt`, droid-ft's driver interface over the twin -- only the
transport (a list of record bytes instead of UDP on loopback, the calibration page's bytes
instead of HTTP) is lockstep's own.  The page's parser, the record's checks and scaling, the
stale rule, the Command rule and the tool-frame wrench are the real ones (docs/ft.md; thesis §7.3).
"""
from __future__ import annotations

import numpy as np

from droid.sim.ft.netft import SENSOR_MODELS, NetFtTwin, NetFtTwinDevice
from droid.sim.lockstep import ORDER_DEVICE, ORDER_WORLD, Scheduler
from droid.sim.lockstep_build import AGENT, AgentLink, LockstepSubunit, brain_databases, builds, local_databases
from droid.subunits.ft.prog import RESTART_S, FtCore, FtGuard, FtStation
from droid.subunits.ft.rdt import (CALIBRATION_PATH, CMD_SET_BIAS, CMD_START_REALTIME, CMD_STOP, RdtStream,
                                   parse_calibration, parse_url, request)

TWIN_HZ = 500  # the twin's world steps a second (records are due at its rdt_rate_hz within them)
FT_HZ = 100  # droid-ft's cycle (its URL's default rate_hz)
STALE_NS = 200_000_000  # sim.toml's stale rule: 12 heartbeat ticks at 60 Hz
#: the URL of a sensor built without a cell (a task's own, as the contact trial's)
DEFAULT_URL = f"netft://127.0.0.1?rate_hz={FT_HZ}"


class TwinNetFt:
    """droid-ft's driver (:class:`droid.subunits.ft.rdt.NetFtDevice`'s interface) on the twin in
    lockstep: requests go to the twin's core as the same bytes, datagrams arrive in :attr:`inbox`
    (filled by the twin's world step while :attr:`alive`) and are checked by the same
    :class:`RdtStream`; the calibration is the twin's page read by the same parser."""

    scheme = "netft"

    def __init__(self, twin: NetFtTwin, url) -> None:
        self.twin, self.url = twin, url
        self.stream = RdtStream()
        self.calibration = None
        self.biased = False
        self.errors = 0
        self.last_error = ""
        self.inbox: list[bytes] = []
        self.alive = True  # False: the twin's datagrams are lost (a test makes the status stale)

    def calibrate(self):
        self.calibration = parse_calibration(self.twin.cal.xml(), f"{self.url.host}:{self.url.http_port}"
                                             f"{CALIBRATION_PATH}")
        return self.calibration

    def start(self) -> bool:
        self.stream.restart()
        self.biased = False
        self.twin.request(request(CMD_START_REALTIME, 0))
        return True

    def bias(self) -> bool:
        self.twin.request(request(CMD_SET_BIAS, 0))
        self.biased = True
        return True

    def stop(self) -> bool:
        self.twin.request(request(CMD_STOP, 0))
        return True

    def poll(self) -> list:
        out = [r for r in (self.stream.feed(d) for d in self.inbox) if r is not None]
        self.inbox.clear()
        return out

    def close(self) -> None:
        pass


class LockstepFt:
    """A wrist F/T sensor on ``arm`` (wcp_global(), contact_wrench_N_Nm()); ``fields`` is the
    newest ``ft6_status`` (a dict, droid.subunits.ft.prog.FtCore.fields); ``cycles`` counts them.
    The sensor is calibrated and streaming from the start (a task's own sensor, already set up)."""

    def __init__(self, sched: Scheduler, arm, T_wcp_sensor, T_sensor_tool, tool_mass_kg: float = 1.5,
                 tool_com_mm=(0.0, 0.0, 60.0), model: str = "gamma", rdt_rate_hz: float = 250.0,
                 seed: int = 7, name: str = "ft") -> None:
        twin = NetFtTwin(SENSOR_MODELS[model], seed, rdt_rate_hz)
        device = NetFtTwinDevice(name, twin, arm, T_wcp_sensor, T_sensor_tool, tool_mass_kg,
                                 tool_com_mm)  # its sockets never open: only true_wrench() is used
        dev = TwinNetFt(twin, parse_url(DEFAULT_URL))
        dev.calibrate()
        dev.start()
        self._start(sched, device, dev, FtCore(np.asarray(T_sensor_tool, float), STALE_NS), FT_HZ, name)

    @classmethod
    def from_device(cls, sched: Scheduler, device: NetFtTwinDevice, dev: TwinNetFt, core: FtCore, name: str,
                    ctrl_status=None, ctrl_command=None) -> "LockstepFt":
        """The twin of world device ``device`` (built by its factory; its sockets never open) read
        through ``dev`` by ``core`` at the URL's ``rate_hz`` [Hz], from power-up (the station
        calibrates and starts it); each cycle's fields also go into ``ctrl_status`` (a record of
        layout ft6_status) and each cycle reads ``ctrl_command`` when given, as droid-ft does."""
        self = cls.__new__(cls)
        self._start(sched, device, dev, core, dev.url.rate_hz, name, ctrl_status, ctrl_command)
        return self

    def _start(self, sched: Scheduler, device: NetFtTwinDevice, dev: TwinNetFt, core: FtCore, ft_hz: float,
               name: str, ctrl_status=None, ctrl_command=None) -> None:
        self.sched = sched
        self.twin = device.twin
        self.device = device
        self.dev = dev
        self.core = core
        self.station = FtStation(dev, core, int(RESTART_S * 1e9), log=self._log)
        self.guard = FtGuard(self.station.rule, None, None, name, self._log)
        self.ctrl_status = ctrl_status
        self.ctrl_command = ctrl_command
        self.fields: dict | None = None
        self.cycles = 0
        self.lines: list[str] = []  # what droid-ft would have said on stderr
        sched.every(TWIN_HZ, self._twin, f"{name}.twin", order=ORDER_WORLD)
        sched.every(ft_hz, self._ft, f"{name}.droid-ft", order=ORDER_DEVICE)

    @property
    def alive(self) -> bool:
        return self.dev.alive

    @alive.setter
    def alive(self, on: bool) -> None:
        self.dev.alive = on

    @property
    def biased(self) -> bool:
        return self.dev.biased

    def bias(self) -> None:
        """Send the software-bias command (the present reading is subtracted from what follows)."""
        self.dev.bias()

    def guard_arm(self, arm_status, arm_name: str) -> None:
        """Hold the over-force guard on ``arm_name``'s Status record ``arm_status`` (its ctrl_status)."""
        self.guard.arm_status, self.guard.arm_name = arm_status, arm_name

    def _log(self, line: str) -> None:
        self.lines.append(line)

    def _twin(self, t_ns: int) -> None:
        recs = self.twin.step(1.0 / TWIN_HZ, self.device.true_wrench)
        if self.dev.alive:
            self.dev.inbox.extend(recs)

    def _ft(self, t_ns: int) -> None:
        command = self.ctrl_command.read() if self.ctrl_command is not None else None
        self.fields = self.station.step(t_ns, command)
        if self.ctrl_status is not None:
            self.ctrl_status.update(**self.fields)
        self.guard.step(self.fields)
        self.cycles += 1


def _address(url) -> tuple[str, int]:
    return url.host, url.port


@builds("droid-ft", AGENT)
def build(ctx, sub) -> LockstepSubunit:
    """The lockstep slot of the F/T package (droid.sim.lockstep_build): the ``netft`` world device at
    the subunit's URL (host and port), on the arm it names (``ctx.twins``), read at the URL's
    ``rate_hz`` by droid-ft's station (calibration page, start, bias on the Command, the cell's
    stale rule) into ``ctrl_status``, with its over-force guard on the subunit's ``guard_arm``
    (that arm's ``ctrl_status``, once every subunit is built); droid-agent and droid-remote carry
    it to and from the Brain (:class:`AgentLink`)."""
    from types import SimpleNamespace

    from droid.cli import BadInput
    from droid.sim.ft.netft import make_netft
    from droid.subunits.ft.prog import ft_options

    opts = ft_options(sub, ctx.cell)
    url = parse_url(opts.url)
    found = [(n, o) for n, o in ctx.world_devices("netft").items()
             if _address(parse_url(str(o.get("device")), any_port=True)) == _address(url)]
    if not found:
        raise BadInput(f"{ctx.where(sub)} has no twin: no [world.devices.*] of type netft answers at "
                       f"{url.host}:{url.port}")
    (device_name, options), = found[:1]
    world = SimpleNamespace(devices=ctx.twins, seed=ctx.seed, cell=ctx.cell)
    device = make_netft(world, device_name, options)
    brain, local = brain_databases(sub), local_databases(sub)
    core = FtCore(opts.T_sensor_tool, ctx.cell.stale_ticks * ctx.cell.period_ns)
    ft = LockstepFt.from_device(ctx.sched, device, TwinNetFt(device.twin, url), core, sub.name,
                                local["ctrl_status"], local.get("ctrl_command"))
    if opts.guard_arm:
        ctx.after(lambda: _guard(ctx, sub, ft, opts.guard_arm))
    link = AgentLink(ctx, sub, brain, local)
    stations = {"droid-ft": [f"{sub.name}.droid-ft"], AGENT: [link.task]}
    return LockstepSubunit(sub.name, sub.cls, brain["status"], brain.get("command"),
                           {p: t for p, t in stations.items() if p in sub.programs}, None, ft)


def _guard(ctx, sub, ft: LockstepFt, arm_name: str) -> None:
    from droid.cli import BadInput

    arm_status = getattr(getattr(ctx.built.get(arm_name), "parts", None), "ctrl_status", None)
    if arm_status is None:
        raise BadInput(f"{ctx.where(sub)}: guard_arm {arm_name!r} has no arm status in lockstep")
    ft.guard_arm(arm_status, arm_name)
