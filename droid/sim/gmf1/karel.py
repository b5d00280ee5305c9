"""The GM Fanuc S400 in droid-sim: KAREL controller on a serial port + two encoder cards (thesis §2.4, §4.2).

Device type ``karel_s400`` (cell file)::

    [world.devices.gmf1]
    type = "karel_s400"
    subunit = "gmf1"                  # whose [subunits.gmf1] serial, encoders, robot and base to use
                                      # (default: the device's name)
    seed = 3                          # power-up counter values (default: the world seed)
    start_deg = [10, 15, 5, 0, 30, 0] # joint angles at power-up [deg] (not the home pose), or
    # wcp = [x, y, z, A, B, C]        # the power-up wrist-centre pose in the global frame
                                      # (mm, ZYZ deg; joints by IK and the pick nearest zero)
    cycle_hz = 6.0                    # KAREL interpreter cycle (thesis §4.2.4)
    speed_mm_s = 300.0                # wrist-centre speed cap
    joint_speed_fraction = 0.5        # of the robot model's joint velocity limits
    ramp_s = 0.3                      # trapezoid ramps
    reply_delay_s = 0.03              # line read -> reply
    dynamics = true                   # the arm of the robot file's [dynamics]/[axis_servo] follows
                                      # KAREL's path (default: true when the file has both tables;
                                      # false: an ideal arm on the path)
    inpos_deg = 1e-4                  # with dynamics: DONE waits for every motor this close [deg]

The serial port is the subunit's ``serial`` key: a path (default
``{run}/NAME.tty``) becomes a symlink to a fresh pseudo-terminal's slave;
``socket://HOST:PORT`` makes the controller listen there.  The encoder cards are
the subunit's ``encoders`` URLs, which must be ``shm://`` for the twin.

Each world step: read what the program wrote, run the controller to the step's
end (bytes in and out at 9600 baud, interpreter, motion), write the reply bytes
that are due, and update the cards' counters from the joint angles.
The device also offers ``wcp_global()`` — the true wrist-centre pose [4x4, mm]
in the global frame — for other twins (the arm-twin interface of the world).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from droid.cli import BadInput, RuntimeFailure
from droid.numbers import finite_numbers
from droid.kinematics import Unreachable, load_robot
from droid.kinematics.transforms import pose_to_T
from droid.sim.gmf1.cards import Quad04Twin, SharedCard
from droid.sim.gmf1.controller import KarelController, KarelParams
from droid.arm.rigid_body import world_backend
from droid.sim.serial_cable import PtyEnd, TcpEnd
from droid.sim.device import Device, arm_subunit, number_options
from droid.subunits.gmf1.config import gmf1_config

DEFAULT_START_DEG = (10.0, 15.0, 5.0, 0.0, 30.0, 0.0)
OPTIONS = ("subunit", "seed", "start_deg", "wcp", "cycle_hz", "speed_mm_s", "joint_speed_fraction", "ramp_s",
           "reply_delay_s", "dynamics", "inpos_deg")
PARAM_OPTIONS = ("cycle_hz", "speed_mm_s", "joint_speed_fraction", "ramp_s", "reply_delay_s", "inpos_deg")


class KarelDevice(Device):
    """Controller core + transport + card twin, stepped by the world."""
    step_s = 0.002  # the controller's motion on absolute time, its 9600-baud bytes (~2 a step), the cards

    def __init__(self, name: str, controller: KarelController, twin: Quad04Twin, transport,
                 model_global, cards: list | None = None) -> None:
        self.name = name
        self.controller = controller
        self.twin = twin
        self.transport = transport
        self.model_global = model_global
        self._cards = cards or []
        self._gearing = controller.model.gearing
        self.t_s = 0.0
        self.bytes_in = 0
        self.bytes_out = 0
        self.halted = False  # fault injection: the KAREL program hangs (reads nothing, answers nothing)
        self._wcp_q: tuple | None = None  # the true joint angles of the cached wrist-centre pose (dtype, bytes)
        self._wcp = None

    def advance(self, dt_s: float) -> None:
        t0 = self.t_s
        self.t_s = t1 = t0 + dt_s
        c = self.controller
        data = self.transport.read_available()
        if self.halted:
            self.twin.update(None)
            return
        if data:
            self.bytes_in += len(data)
            c.receive(data, t0)
        c.advance(t1)
        out = c.transmit(t1)
        if out:
            self.bytes_out += len(out)
            self.transport.write(out)
        if c.moved:
            c.moved = False
            self.twin.update(self._gearing.joints_to_counts(c.q_motor_deg))
        else:
            self.twin.update(None)

    def wcp_global(self) -> np.ndarray:
        """True wrist-centre pose (4x4, mm) in the global frame (a copy: the caller's to keep).

        Computed when the true joint angles change (bit for bit: the pose is a function of them
        alone); the holder at rest costs the sensor twins no forward kinematics."""
        q = self.controller.q_deg
        a = np.asarray(q)
        key = (a.dtype.str, a.tobytes())
        if key != self._wcp_q:
            self._wcp, self._wcp_q = self.model_global.fk(q), key
        return self._wcp.copy()

    def close(self) -> None:
        self.twin.release()
        for card in self._cards:
            card.close()
        self._cards = []
        if self.transport is not None:
            self.transport.close()
            self.transport = None


def karel_params(options: dict, where: str, model=None) -> KarelParams:
    """The controller's parameters from a device table; ``dynamics`` defaults to whether ``model``
    (the robot file) has the ``[dynamics]`` and ``[axis_servo]`` tables the arm twin needs."""
    kw = {}
    has_dynamics = model is not None and model.dynamics is not None and model.axis_servo is not None
    if "dynamics" in options:
        v = options["dynamics"]
        if not isinstance(v, bool):
            raise BadInput(f"{where} dynamics must be true or false, got {v!r}")
        if v and not has_dynamics:
            raise BadInput(f"{where} dynamics = true needs [dynamics] and [axis_servo] in the robot file"
                           + (f" {model.name}" if model is not None else ""))
        kw["dynamics"] = v
    else:
        kw["dynamics"] = has_dynamics
    kw.update(number_options(options, PARAM_OPTIONS, where))
    try:
        return KarelParams(**kw)
    except ValueError as exc:
        raise BadInput(f"{where} {exc}") from None


def start_joints(options: dict, model, model_global, where: str) -> np.ndarray:
    """Power-up joint angles [deg] from ``start_deg`` or ``wcp`` (global pose, by IK)."""
    if "wcp" in options:
        if "start_deg" in options:
            raise BadInput(f"{where} give start_deg or wcp, not both")
        wcp = options["wcp"]
        if not finite_numbers(wcp, 6):
            raise BadInput(f"{where} wcp must be 6 finite numbers: x y z [mm] A B C [ZYZ deg]")
        try:
            return model_global.ik(pose_to_T(*wcp), np.zeros(6))
        except Unreachable as exc:
            raise BadInput(f"{where} wcp {wcp} is out of reach of {model.name}: {exc}") from None
    q = options.get("start_deg", list(DEFAULT_START_DEG))
    if not finite_numbers(q, 6):
        raise BadInput(f"{where} start_deg must be 6 joint angles [deg]")
    q = np.array(q, float)
    why = model.limit_violation(q)
    if why:
        raise BadInput(f"{where} start_deg outside the joint limits: {why}")
    return q


def make_karel(world, name: str, options: dict) -> KarelDevice:
    """Factory of the ``karel_s400`` device type (see the module docstring)."""
    cell = world.cell
    where, sub = arm_subunit(world, name, options, OPTIONS)
    cfg = gmf1_config(cell, sub)
    model = load_robot(sub.robot)
    params = karel_params(options, where, model)
    if cfg.baud != params.baud:
        params = dataclasses.replace(params, baud=cfg.baud)
    model_global = model.with_base(pose_to_T(*sub.base))
    q0 = start_joints(options, model, model_global, where)
    seed = options.get("seed", world.seed)
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise BadInput(f"{where} seed must be an integer")
    for url in cfg.encoders:
        if not url.startswith("shm://"):
            raise BadInput(f"{where} the simulated encoder cards need shm:// URLs, got {url!r}")
    cards: list[SharedCard] = []
    twin = None
    try:
        for url in cfg.encoders:
            cards.append(SharedCard(url[len("shm://"):]))
        twin = Quad04Twin([c.buf for c in cards], np.random.default_rng(seed))
        controller = KarelController(model, params, q0, rigid_body=world_backend())
        twin.update(model.gearing.joints_to_counts(controller.q_motor_deg))
        if cfg.serial.startswith("socket://"):
            try:
                transport = TcpEnd(cfg.serial)
            except ValueError as exc:
                raise BadInput(f"{where} {exc}") from None
            except OSError as exc:
                raise RuntimeFailure(f"{where} cannot listen on {cfg.serial}: {exc.strerror}") from None
        elif "://" in cfg.serial:
            raise BadInput(f"{where} the simulated controller serves a pty path or socket://HOST:PORT, "
                           f"not {cfg.serial!r}")
        else:
            try:
                transport = PtyEnd(cfg.serial)
            except OSError as exc:
                raise RuntimeFailure(f"{where} cannot publish the serial port at {cfg.serial}: "
                                     f"{exc.strerror}") from None
    except BaseException:
        if twin is not None:
            twin.release()
        for c in cards:
            c.close()
        raise
    return KarelDevice(name, controller, twin, transport, model_global, cards)
