"""The joystick in lockstep: its twin's js_event bytes read by droid-joystick's station (thesis §2.6, §3.4).

=====================  ==========  ==============================================
task                   rate        stands for
=====================  ==========  ==============================================
``NAME.twin``          its rate    droid-sim's ``joystick`` device (the stick, its script)
``NAME.joystick``      its rate    droid-joystick (:class:`JoystickStation`: read, Status fields)
``NAME.agent_link``    tick        droid-agent and droid-remote (ctrl_status -> Brain Status)
=====================  ==========  ==============================================

The rate is the subunit's ``rate_hz`` (default: droid-joystick's declared rate, the registry's).
Only the transport is lockstep's own: the twin's bytes go to the driver's parser through a list
instead of a pseudo-terminal (:class:`MemoryJs`).  ``parts.twin.move(axes, buttons)`` moves the
stick from a test.
"""
from __future__ import annotations

from urllib.parse import urlsplit

from droid.sim.joystick.device import JoystickTwin, joystick_twin
from droid.sim.lockstep import ORDER_DEVICE, ORDER_WORLD
from droid.sim.lockstep_build import AGENT, AgentLink, LockstepSubunit, brain_databases, builds, local_databases
from droid.subunits.joystick.driver import JsDevice
from droid.subunits.joystick.station import JoystickStation


class MemoryJs(JsDevice):
    """The js driver over bytes handed to it (:meth:`feed`) instead of a device file: always open."""

    def open(self) -> bool:
        if self.fd < 0:
            self.fd, self.opens, self.state.valid = 0, self.opens + 1, True
        return True

    def feed(self, data: bytes) -> None:
        self._waiting = getattr(self, "_waiting", b"") + data

    def poll(self) -> int:
        self.open()
        data, self._waiting = getattr(self, "_waiting", b""), b""
        return self.parser.feed(data) if data else 0


class LockstepJoystick:
    """The twin and droid-joystick's station of one subunit on ``sched`` (see the module docstring)."""

    def __init__(self, sched, name: str, twin: JoystickTwin, rate_hz: float, ctrl_status) -> None:
        self.sched = sched
        self.twin = twin
        self.dev = MemoryJs(f"lockstep:{name}", {})
        self.station = JoystickStation(self.dev, rate_hz, log=lambda line: None)
        self.ctrl_status = ctrl_status
        self.dt_s = 1.0 / rate_hz
        self.dev.feed(twin.advance(0.0))
        ctrl_status.update(**self.station.start(sched.t_ns))
        sched.every(rate_hz, self._twin, f"{name}.twin", order=ORDER_WORLD)
        sched.every(rate_hz, self._station, f"{name}.joystick", order=ORDER_DEVICE)

    def _twin(self, t_ns: int) -> None:
        self.dev.feed(self.twin.advance(self.dt_s))

    def _station(self, t_ns: int) -> None:
        self.ctrl_status.update(**self.station.cycle(t_ns))


def _twin_for(ctx, sub) -> JoystickTwin:
    """The twin of the ``joystick`` world device at the subunit's device path (a centred 2-axis,
    8-button stick when the world has none)."""
    from types import SimpleNamespace

    path = urlsplit(str(sub.options.get("device", ""))).path
    world = SimpleNamespace(devices=ctx.twins, seed=ctx.seed, cell=ctx.cell)
    for name, options in ctx.world_devices("joystick").items():
        if options.get("device") == path:
            return joystick_twin(world, name, dict(options))[1]
    return JoystickTwin()


@builds("droid-joystick", AGENT)
def build(ctx, sub) -> LockstepSubunit:
    """The lockstep slot of the joystick package (droid.sim.lockstep_build)."""
    from droid.subunits.joystick.prog import joystick_options

    _url, rate_hz = joystick_options(sub)
    brain, local = brain_databases(sub), local_databases(sub)
    stick = LockstepJoystick(ctx.sched, sub.name, _twin_for(ctx, sub), rate_hz, local["ctrl_status"])
    if "droid-joystick" not in sub.programs:
        ctx.sched.remove(f"{sub.name}.joystick")
    link = AgentLink(ctx, sub, brain, local)
    stations = {"droid-joystick": [f"{sub.name}.joystick"], AGENT: [link.task]}
    return LockstepSubunit(sub.name, sub.cls, brain["status"], brain.get("command"),
                           {p: t for p, t in stations.items() if p in sub.programs}, None, stick)
