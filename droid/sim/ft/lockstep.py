"""The F/T sensor in lockstep: the Net F/T twin's core and droid-ft's core on one scheduler.

The twin (:class:`droid.sim.ft.netft.NetFtTwin`) is stepped in world time at
``PLANT_HZ`` and streams its RDT records; droid-ft's core (:class:`FtCore`, through the
driver's checks :class:`RdtStream`) reads every record waiting at droid-ft's rate and makes
the ``ft6_status`` fields, as ``droid-ft`` does (docs/ft.md) -- only the transport (a list of
record bytes instead of UDP on loopback) is lockstep's own.  The record's bytes, scaling,
stale rule and tool-frame wrench are the real ones.
"""
from __future__ import annotations

import numpy as np

from droid.sim.ft.netft import SENSOR_MODELS, NetFtTwin, NetFtTwinDevice
from droid.sim.lockstep import ORDER_DEVICE, ORDER_WORLD, Scheduler
from droid.sim.lockstep_build import AGENT, AgentLink, LockstepSubunit, brain_databases, builds, local_databases
from droid.subunits.ft.prog import FtCore
from droid.subunits.ft.rdt import CMD_SET_BIAS, CMD_START_REALTIME, RDT_HEADER, REQUEST, RdtStream

TWIN_HZ = 500  # the twin's world steps a second (records are due at its rdt_rate_hz within them)
FT_HZ = 100  # droid-ft's cycle (its URL's default rate_hz)
STALE_NS = 200_000_000  # sim.toml's stale rule: 12 heartbeat ticks at 60 Hz


class LockstepFt:
    """A wrist F/T sensor on ``arm`` (wcp_global(), contact_wrench_N_Nm()); ``fields`` is the
    newest ``ft6_status`` (a dict, droid.subunits.ft.prog.FtCore.fields); ``cycles`` counts them."""

    def __init__(self, sched: Scheduler, arm, T_wcp_sensor, T_sensor_tool, tool_mass_kg: float = 1.5,
                 tool_com_mm=(0.0, 0.0, 60.0), model: str = "gamma", rdt_rate_hz: float = 250.0,
                 seed: int = 7, name: str = "ft") -> None:
        twin = NetFtTwin(SENSOR_MODELS[model], seed, rdt_rate_hz)
        device = NetFtTwinDevice(name, twin, arm, T_wcp_sensor, T_sensor_tool, tool_mass_kg,
                                 tool_com_mm)  # its sockets never open: only true_wrench() is used
        self._start(sched, device, FtCore(np.asarray(T_sensor_tool, float), STALE_NS), FT_HZ, name)

    @classmethod
    def from_device(cls, sched: Scheduler, device: NetFtTwinDevice, core: FtCore, ft_hz: float, name: str,
                    ctrl_status=None) -> "LockstepFt":
        """The twin of world device ``device`` (built by its factory; its sockets never open) read by
        ``core`` at ``ft_hz`` [Hz]; each cycle's fields also go into ``ctrl_status`` (a record of
        layout ft6_status) when given, as droid-ft writes them."""
        self = cls.__new__(cls)
        self._start(sched, device, core, ft_hz, name, ctrl_status)
        return self

    def _start(self, sched: Scheduler, device: NetFtTwinDevice, core: FtCore, ft_hz: float, name: str,
               ctrl_status=None) -> None:
        self.sched = sched
        self.twin = device.twin
        self.device = device
        self.core = core
        self.ctrl_status = ctrl_status
        self.stream = RdtStream()
        self.inbox: list[bytes] = []
        self.fields: dict | None = None
        self.cycles = 0
        self.alive = True  # False: the twin stops sending (a test makes the status stale)
        self.biased = False
        self.twin.request(REQUEST.pack(RDT_HEADER, CMD_START_REALTIME, 0))
        sched.every(TWIN_HZ, self._twin, f"{name}.twin", order=ORDER_WORLD)
        sched.every(ft_hz, self._ft, f"{name}.droid-ft", order=ORDER_DEVICE)

    def bias(self) -> None:
        """Send the software-bias command (the present reading is subtracted from what follows)."""
        self.twin.request(REQUEST.pack(RDT_HEADER, CMD_SET_BIAS, 0))
        self.biased = True

    def _twin(self, t_ns: int) -> None:
        recs = self.twin.step(1.0 / TWIN_HZ, self.device.true_wrench)
        if self.alive:
            self.inbox.extend(recs)

    def _ft(self, t_ns: int) -> None:
        records = [r for r in (self.stream.feed(d) for d in self.inbox) if r is not None]
        self.inbox.clear()
        self.core.on_records(records, self.twin.cal, t_ns)
        self.fields = self.core.fields(self.stream, self.twin.cal, self.biased, t_ns)
        if self.ctrl_status is not None:
            self.ctrl_status.update(**self.fields)
        self.cycles += 1


def _address(url) -> tuple[str, int]:
    return url.host, url.port


@builds("droid-ft", AGENT)
def build(ctx, sub) -> LockstepSubunit:
    """The lockstep slot of the F/T package (droid.sim.lockstep_build): the ``netft`` world device at
    the subunit's URL (host and port), on the arm it names (``ctx.twins``), read at the URL's
    ``rate_hz`` by droid-ft's core with the cell's stale rule into ``ctrl_status``; droid-agent and
    droid-remote carry it to the Brain Status (:class:`AgentLink`).  Not in lockstep: the Brain
    Command's bias and over-force guard (droid-ft's FtStation), the calibration page."""
    from types import SimpleNamespace

    from droid.cli import BadInput
    from droid.sim.ft.netft import make_netft
    from droid.subunits.ft.prog import ft_options
    from droid.subunits.ft.rdt import parse_url

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
    ft = LockstepFt.from_device(ctx.sched, device, core, url.rate_hz, sub.name, local["ctrl_status"])
    link = AgentLink(ctx, sub, brain, local)
    stations = {"droid-ft": [f"{sub.name}.droid-ft"], AGENT: [link.task]}
    return LockstepSubunit(sub.name, sub.cls, brain["status"], brain.get("command"),
                           {p: t for p, t in stations.items() if p in sub.programs}, None, ft)
